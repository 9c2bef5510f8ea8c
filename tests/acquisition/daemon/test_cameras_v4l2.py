"""Unit tests of our V4L2 camera logic with cv2.VideoCapture replaced by a fake.

No device is involved: these check what our code asks of OpenCV and how it reacts to what a
driver answers (modes refused, exposure ignored, stale buffers, no frame, another pixel format
than asked). The fake hands the bytes OpenCV's V4L2 backend hands with CAP_PROP_CONVERT_RGB
off: YUYV as (height, width, 2), luma first (older OpenCV: one row of those bytes), MJPEG as
one row of the JPEG's bytes (built here from a known image with cv2.imencode, as a UVC camera
compresses colour). Whether a real camera behaves like the fake must be checked on the rig.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np
import pytest

import acquisition.cameras_v4l2 as v4l2
from acquisition.contracts.camera import Camera, CameraError, CameraTimeoutError
from acquisition.cameras_v4l2 import V4L2Camera, stable_device_id


class FakeCapture:
    """A V4L2 device as OpenCV shows it: properties, a queue of buffered frames."""

    instances: ClassVar[list[FakeCapture]] = []

    def __init__(self, device: str, backend: int) -> None:
        self.device, self.backend = device, backend
        self.opened = device != "/dev/missing"
        self.props: dict[int, float] = {cv2.CAP_PROP_AUTO_EXPOSURE: 3.0}
        self.calls: list[int] = []
        self.refuse: set[int] = set()  # properties the "driver" ignores
        self.stale = 3  # buffers queued before the request
        self.stamps = True
        self.props[cv2.CAP_PROP_CONVERT_RGB] = 1.0  # OpenCV's default
        self.frame_shape: tuple[int, int] | None = None  # another size than set
        self.scene: np.ndarray | None = None  # BGR; default: grey 10 x the buffer's number
        # (mod 256)
        self.delivered: str | None = None  # another format than set
        self.flat_yuyv = False  # YUYV as one row of bytes, as older OpenCV hands it
        self.quality = 90  # MJPEG's
        self.released = False
        self.grabs = 0
        self._stamp = 0.0
        FakeCapture.instances.append(self)

    def isOpened(self) -> bool:  # OpenCV spells it so
        return self.opened

    def set(self, prop: int, value: float) -> bool:
        self.calls.append(prop)
        if prop not in self.refuse:
            self.props[prop] = value
        return True  # as OpenCV often does, whatever the driver did

    def get(self, prop: int) -> float:
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self._stamp if self.stamps else 0.0
        return self.props.get(prop, 0.0)

    def grab(self) -> bool:
        self.grabs += 1
        now_ms = time.clock_gettime(time.CLOCK_MONOTONIC) * 1000.0
        if self.stale > 0:  # a buffer filled before the request
            self.stale -= 1
            self._stamp = now_ms - 1000.0
        else:
            self._stamp = now_ms + 0.5
        return True

    def retrieve(self) -> tuple[bool, np.ndarray]:
        h = int(self.props[cv2.CAP_PROP_FRAME_HEIGHT])
        w = int(self.props[cv2.CAP_PROP_FRAME_WIDTH])
        scene = self.scene if self.scene is not None else np.full(
            (*(self.frame_shape or (h, w)), 3), 10 * self.grabs % 256, np.uint8)
        if self.props[cv2.CAP_PROP_CONVERT_RGB]:
            return True, scene  # OpenCV's own BGR
        delivered = self.delivered or _fourcc_text(int(self.props[cv2.CAP_PROP_FOURCC]))
        if delivered == "YUYV":
            raw = yuyv_bytes(cv2.cvtColor(scene, cv2.COLOR_BGR2GRAY))
            return True, raw.reshape(1, -1) if self.flat_yuyv else raw
        return True, mjpeg_bytes(scene, self.quality)

    def release(self) -> None:
        self.released = True


def _fourcc_text(code: int) -> str:
    return "".join(chr((code >> 8 * i) & 0xFF) for i in range(4))


def yuyv_bytes(grey: np.ndarray) -> np.ndarray:
    """A YUYV buffer (height, width, 2) of the grey image: Y0 U0 Y1 V0 ..., with chroma that
    varies (a coloured scene), so that a decoder taking the wrong byte shows it."""
    h, w = grey.shape
    chroma = (np.arange(h * w).reshape(h, w) * 37 % 256).astype(np.uint8)
    return np.stack([grey, chroma], axis=-1)


def mjpeg_bytes(bgr: np.ndarray, quality: int) -> np.ndarray:
    """One row of a JPEG's bytes, as OpenCV's V4L2 backend hands an MJPEG buffer."""
    ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return jpeg.reshape(1, -1)


def scene(h: int, w: int) -> np.ndarray:
    """A BGR view of a checkerboard under a colour gradient, slightly blurred as a lens
    would (what a camera of the rig sees)."""
    v, u = np.mgrid[0:h, 0:w]
    board = np.where((u // 16 + v // 16) % 2 == 0, 200.0, 40.0)
    bgr = np.stack([board * (0.7 + 0.3 * u / w), board, board * (1.0 - 0.3 * v / h)], axis=-1)
    return cv2.GaussianBlur(np.clip(bgr, 0, 255).astype(np.uint8), (5, 5), 1.0)


@pytest.fixture(autouse=True)
def fake_cv2(monkeypatch: pytest.MonkeyPatch) -> None:
    FakeCapture.instances.clear()
    monkeypatch.setattr(v4l2.cv2, "VideoCapture", FakeCapture)


def _camera(**kwargs: Any) -> V4L2Camera:
    args: dict[str, Any] = {"name": "cam0", "device": "/dev/video0", "width": 1280,
                            "height": 720} | kwargs
    return V4L2Camera(**args)


def test_backend_forced_format_first_and_read_back() -> None:
    camera = _camera(fps=30.0, exposure=150.0)
    cap = FakeCapture.instances[0]
    assert isinstance(camera, Camera)
    assert cap.backend == cv2.CAP_V4L2
    assert cap.calls.index(cv2.CAP_PROP_FOURCC) < cap.calls.index(cv2.CAP_PROP_FRAME_WIDTH)
    assert cap.props[cv2.CAP_PROP_AUTO_EXPOSURE] == v4l2.V4L2_EXPOSURE_MANUAL
    assert cap.props[cv2.CAP_PROP_EXPOSURE] == 150.0


@pytest.mark.parametrize(
    ("refused", "kwargs", "words"),
    [({cv2.CAP_PROP_FRAME_WIDTH}, {}, "the driver set MJPG 0x720"),
     ({cv2.CAP_PROP_FOURCC}, {}, "the driver set (none)"),
     ({cv2.CAP_PROP_FPS}, {"fps": 30.0}, "30 frames/s"),
     ({cv2.CAP_PROP_AUTO_EXPOSURE}, {"exposure": 100.0}, "exposure not fixed"),
     ({cv2.CAP_PROP_EXPOSURE}, {"exposure": 100.0}, "exposure not fixed")],
)
def test_a_mode_the_driver_did_not_take_is_an_error(monkeypatch: pytest.MonkeyPatch,
                                                     refused: set[int], kwargs: dict,
                                                     words: str) -> None:
    original = FakeCapture.__init__

    def refusing(self, device, backend):
        original(self, device, backend)
        self.refuse = refused

    monkeypatch.setattr(FakeCapture, "__init__", refusing)
    with pytest.raises(CameraError, match="cam0") as caught:
        _camera(**kwargs)
    assert words in str(caught.value)
    assert FakeCapture.instances[0].released


def test_unopenable_device() -> None:
    with pytest.raises(CameraError, match="cannot open /dev/missing"):
        _camera(device="/dev/missing")


def test_grab_skips_stale_buffers_by_timestamp() -> None:
    camera = _camera(fourcc="YUYV")
    cap = FakeCapture.instances[0]
    frame = camera.grab()
    assert cap.grabs == 4  # three stale buffers drained, the fourth is fresh
    assert frame.image.shape == (720, 1280) and frame.camera == "cam0"
    assert int(frame.image[0, 0]) == 40


def test_grab_without_timestamps_drains_a_fixed_count() -> None:
    camera = _camera(drain_frames=5)
    cap = FakeCapture.instances[0]
    cap.stamps = False
    cap.stale = 0
    camera.grab()
    assert cap.grabs == 6


def test_grab_errors(monkeypatch: pytest.MonkeyPatch) -> None:
    camera = _camera()
    cap = FakeCapture.instances[0]
    cap.stale = 10_000  # the camera only ever delivers old buffers
    with pytest.raises(CameraTimeoutError, match="no fresh frame"):
        camera.grab(timeout_s=0.05)
    cap.stale = 0
    cap.frame_shape = (480, 640)  # a JPEG of another size
    with pytest.raises(CameraError, match="640x480 where 1280x720"):
        camera.grab()
    monkeypatch.setattr(cap, "grab", lambda: False)
    with pytest.raises(CameraError, match="unplugged"):
        camera.grab()


def test_stable_identity_from_by_id(tmp_path: Path) -> None:
    device = tmp_path / "video0"
    device.touch()
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    link = by_id / "usb-Vendor_Cam_SN123-video-index0"
    link.symlink_to(device)
    assert stable_device_id(str(device), by_id) == str(link)
    assert stable_device_id(str(link), by_id) == str(link)
    assert stable_device_id(str(tmp_path / "video9"), by_id) == str(tmp_path / "video9")
    camera = _camera(device=str(device), by_id_dir=by_id)
    assert camera.device_id == str(link)


# ---------------------------------------------------------------------------------------------
# The pixel formats a camera delivers: asked for, decoded to grey, another one reported


@pytest.mark.parametrize("flat", [False, True])
def test_yuyv_gives_the_sensor_s_luma_exactly(flat: bool) -> None:
    camera = _camera(fourcc="YUYV", width=320, height=240)
    cap = FakeCapture.instances[0]
    assert cap.props[cv2.CAP_PROP_FOURCC] == cv2.VideoWriter.fourcc(*"YUYV")
    assert cap.props[cv2.CAP_PROP_CONVERT_RGB] == 0  # the camera's own bytes
    cap.scene, cap.flat_yuyv = scene(240, 320), flat
    grey = camera.grab().image
    assert grey.dtype == np.uint8 and grey.flags.c_contiguous
    np.testing.assert_array_equal(grey, cv2.cvtColor(cap.scene, cv2.COLOR_BGR2GRAY))


@pytest.mark.parametrize(("quality", "rms_max"), [(95, 1.5), (75, 4.0)])
def test_mjpeg_gives_the_luma_within_the_compression_s_error(quality: int,
                                                             rms_max: float) -> None:
    """JPEG codes the luma with BT.601's weights, as OpenCV's BGR to grey; what is left is
    the compression's own error on the board's edges (RMS 1.1 grey levels at quality 95, 3.1
    at 75 for this scene), unbiased; a wrong channel or weighting would be tens of levels
    off, or biased."""
    camera = _camera(width=320, height=240)
    cap = FakeCapture.instances[0]
    cap.scene, cap.quality = scene(240, 320), quality
    grey = camera.grab().image
    source = cv2.cvtColor(cap.scene, cv2.COLOR_BGR2GRAY).astype(float)
    assert grey.shape == (240, 320) and grey.dtype == np.uint8
    error = grey - source
    assert np.sqrt(np.mean(error**2)) < rms_max and np.abs(error).max() < 5 * rms_max
    assert abs(np.mean(error)) < 0.1


@pytest.mark.parametrize(("asked", "delivered", "words"), [
    ("YUYV", "MJPG", "asked for YUYV, it delivered a JPEG frame (MJPG) where a YUYV frame is "
                     "153600 bytes"),
    ("MJPG", "YUYV", "asked for MJPG, it delivered a raw buffer of 2 bytes per pixel (YUYV)"),
])
def test_a_camera_delivering_another_format_than_asked_is_reported(asked: str, delivered: str,
                                                                   words: str) -> None:
    camera = _camera(fourcc=asked, width=320, height=240)
    FakeCapture.instances[0].delivered = delivered
    with pytest.raises(CameraError, match="changed the format without saying so") as caught:
        camera.grab()
    assert words in str(caught.value) and "cam0" in str(caught.value)


def test_a_jpeg_cut_short_and_no_raw_buffers_are_errors(monkeypatch: pytest.MonkeyPatch) -> None:
    camera = _camera(width=320, height=240)
    cap = FakeCapture.instances[0]
    whole = mjpeg_bytes(scene(240, 320), 90)
    monkeypatch.setattr(cap, "retrieve", lambda: (True, whole[:, :200]))
    with pytest.raises(CameraError, match="could not be decoded"):
        camera.grab()
    original = FakeCapture.__init__

    def converting(self, device, backend):
        original(self, device, backend)
        self.refuse = {cv2.CAP_PROP_CONVERT_RGB}

    monkeypatch.setattr(FakeCapture, "__init__", converting)
    with pytest.raises(CameraError, match="CAP_PROP_CONVERT_RGB stayed on"):
        _camera()
    with pytest.raises(CameraError, match="'H264' is not one micam reads"):
        _camera(fourcc="H264")
