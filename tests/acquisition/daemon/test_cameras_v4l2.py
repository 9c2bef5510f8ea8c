"""Unit tests of our V4L2 camera logic with cv2.VideoCapture replaced by a fake.

No device is involved: these check what our code asks of OpenCV and how it reacts to what a
driver answers (modes refused, exposure ignored, stale buffers, no frame). Whether a real
camera behaves like the fake must be checked on the rig.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import ClassVar

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
        self.frame_shape: tuple[int, ...] | None = None
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
        shape = self.frame_shape or (h, w, 3)
        return True, np.full(shape, self.grabs, np.uint8)

    def release(self) -> None:
        self.released = True


@pytest.fixture(autouse=True)
def fake_cv2(monkeypatch: pytest.MonkeyPatch) -> None:
    FakeCapture.instances.clear()
    monkeypatch.setattr(v4l2.cv2, "VideoCapture", FakeCapture)


def _camera(**kwargs) -> V4L2Camera:
    args = {"name": "cam0", "device": "/dev/video0", "width": 1280, "height": 720} | kwargs
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
    camera = _camera()
    cap = FakeCapture.instances[0]
    frame = camera.grab()
    assert cap.grabs == 4  # three stale buffers drained, the fourth is fresh
    assert frame.image.shape == (720, 1280, 3) and frame.camera == "cam0"
    assert int(frame.image[0, 0, 0]) == 4


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
    cap.frame_shape = (480, 640, 3)
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
