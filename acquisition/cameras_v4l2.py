"""A real camera through OpenCV's V4L2 backend, behind the `acquisition.contracts.camera.Camera` protocol.

What it guarantees, and why:
- the V4L2 backend is forced (`cv2.CAP_V4L2`): property handling is backend-specific, and
  OpenCV could otherwise pick another backend silently;
- the pixel format (FOURCC) is set first, then the resolution and frame rate, and all are read
  back: `set()` can report success while the driver keeps another mode, so a mismatch, and a
  first frame of the wrong shape, are errors rather than silently different images;
- the frames are the camera's own bytes, decoded to grey here (CAP_PROP_CONVERT_RGB off, read
  back): YUYV's luma bytes exactly as the sensor's pipeline gave them, MJPEG's JPEG decoded to
  grey by `cv2.imdecode` (its Y plane, as OpenCV's own conversion decodes it, without the
  round trip through BGR and back); the checkerboard needs no colour. Each buffer is checked
  against the format asked for, so a camera that silently delivers another (JPEG bytes
  where YUYV was set, a raw 4:2:2 buffer where MJPG was, a JPEG of another size) is an error
  naming both formats rather than a garbled image;
- exposure is fixed (auto exposure off, then the value, read back) so that every pose is
  exposed alike;
- `grab` returns a frame taken after the call began: V4L2 queues several buffers, so stale
  ones are drained until a buffer's timestamp (CAP_PROP_POS_MSEC: the V4L2 buffer time, on
  CLOCK_MONOTONIC for uvcvideo) is later than the request; when the driver gives no timestamp,
  or one on another clock, `drain_frames` buffers are discarded first instead;
- the device identity is stable across reboots and USB re-plugging: the /dev/v4l/by-id link
  of the device (which names vendor, model and serial), not /dev/videoN.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from acquisition.contracts.camera import CameraError, CameraTimeoutError, Frame, PixelFormat
from daq import ClosesOnExit

BY_ID_DIR = Path("/dev/v4l/by-id")
V4L2_EXPOSURE_MANUAL = 1  # V4L2_EXPOSURE_MANUAL in raw (non-normalised) property mode
_MAX_GRABS = 64
_CLOCK_SLACK_MS = 1000.0  # a buffer time further ahead than this is not on CLOCK_MONOTONIC
PIXEL_FORMATS: tuple[PixelFormat, ...] = ("MJPG", "YUYV")
JPEG_START = b"\xff\xd8"  # a JPEG's start-of-image marker: every MJPEG frame begins with it


def stable_device_id(device: str, by_id_dir: Path = BY_ID_DIR) -> str:
    """The /dev/v4l/by-id path of `device` (itself if it is one), else the device path."""
    path = Path(device)
    if path.parent == by_id_dir:
        return str(path)
    try:
        target = path.resolve(strict=True)
        for link in sorted(by_id_dir.iterdir()):
            if link.resolve() == target:
                return str(link)
    except OSError:
        pass
    return str(path)


class V4L2Camera(ClosesOnExit):
    """One UVC/V4L2 camera in a fixed mode (see the module docstring)."""

    def __init__(self, name: str, device: str, width: int, height: int,
                 fourcc: PixelFormat = "MJPG", fps: float | None = None,
                 exposure: float | None = None, drain_frames: int = 4,
                 by_id_dir: Path = BY_ID_DIR) -> None:
        if fourcc not in PIXEL_FORMATS:
            raise CameraError(f"camera {name}: pixel format {fourcc!r} is not one micam reads; "
                              f"ask for one of {', '.join(PIXEL_FORMATS)}")
        self._name = name
        self._device_id = stable_device_id(device, by_id_dir)
        self._drain = drain_frames
        self._fourcc = fourcc
        self._cap = cv2.VideoCapture(device, cv2.CAP_V4L2)
        if not self._cap.isOpened():
            raise CameraError(f"camera {name}: cannot open {device} with V4L2; check that it is "
                              "plugged in and that this user is in the 'video' group")
        try:
            self._configure(fourcc, width, height, fps, exposure)
        except BaseException:
            self._cap.release()
            raise
        self._shape = (height, width)

    @property
    def name(self) -> str:
        return self._name

    @property
    def device_id(self) -> str:
        return self._device_id

    def _configure(self, fourcc: str, width: int, height: int, fps: float | None,
                   exposure: float | None) -> None:
        cap = self._cap
        code = cv2.VideoWriter.fourcc(*fourcc)
        cap.set(cv2.CAP_PROP_FOURCC, code)
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        if fps is not None:
            cap.set(cv2.CAP_PROP_FPS, fps)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # best effort: fewer stale buffers to drain
        got_code = int(cap.get(cv2.CAP_PROP_FOURCC))
        got = (round(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), round(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        if got_code != code or got != (width, height):
            raise CameraError(
                f"camera {self._name} ({self._device_id}): asked for {fourcc} {width}x{height}, "
                f"the driver set {_fourcc_text(got_code)} {got[0]}x{got[1]}; choose a mode the "
                "camera lists (`v4l2-ctl --list-formats-ext`)")
        if fps is not None and abs(cap.get(cv2.CAP_PROP_FPS) - fps) > 0.5:
            raise CameraError(f"camera {self._name}: asked for {fps:g} frames/s, the driver set "
                              f"{cap.get(cv2.CAP_PROP_FPS):g}")
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        if cap.get(cv2.CAP_PROP_CONVERT_RGB) != 0:
            raise CameraError(f"camera {self._name}: OpenCV's V4L2 backend would not hand over "
                              "the camera's own bytes (CAP_PROP_CONVERT_RGB stayed on); use an "
                              "OpenCV built with V4L2 (`cv2.getBuildInformation()`)")
        if exposure is not None:
            cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, V4L2_EXPOSURE_MANUAL)
            cap.set(cv2.CAP_PROP_EXPOSURE, exposure)
            auto = cap.get(cv2.CAP_PROP_AUTO_EXPOSURE)
            value = cap.get(cv2.CAP_PROP_EXPOSURE)
            if auto != V4L2_EXPOSURE_MANUAL or abs(value - exposure) > 1e-6 * max(1.0, exposure):
                raise CameraError(
                    f"camera {self._name}: exposure not fixed (auto mode {auto:g}, value "
                    f"{value:g} instead of {exposure:g}); some UVC drivers need auto exposure "
                    "switched off with `v4l2-ctl -c auto_exposure=1` first")

    def grab(self, timeout_s: float = 2.0) -> Frame:
        """A frame exposed after this call began (CameraTimeoutError if none within timeout_s)."""
        requested_ms = time.clock_gettime(time.CLOCK_MONOTONIC) * 1000.0
        deadline = time.monotonic() + timeout_s
        for grabs in range(1, _MAX_GRABS + 1):
            if time.monotonic() > deadline:
                break
            if not self._cap.grab():
                raise CameraError(f"camera {self._name} ({self._device_id}) returned no frame; "
                                  "it may have been unplugged")
            stamp_ms = self._cap.get(cv2.CAP_PROP_POS_MSEC)
            now_ms = time.clock_gettime(time.CLOCK_MONOTONIC) * 1000.0
            if 0 < stamp_ms <= now_ms + _CLOCK_SLACK_MS:  # a monotonic buffer time
                fresh = stamp_ms > requested_ms
            else:
                fresh = grabs > self._drain
            if fresh:
                return Frame(image=self._retrieve(), timestamp_s=time.monotonic(),
                             camera=self._name)
        raise CameraTimeoutError(f"camera {self._name} ({self._device_id}) gave no fresh frame "
                                 f"within {timeout_s:g} s")

    def _retrieve(self) -> np.ndarray:
        """The grabbed buffer as a grey (height, width) uint8 image."""
        ok, raw = self._cap.retrieve()
        if not ok or raw is None:
            raise CameraError(f"camera {self._name}: returned no buffer for the frame")
        image = self._grey(np.asarray(raw, dtype=np.uint8))
        if image.shape[:2] != self._shape:
            raise CameraError(f"camera {self._name}: frame of {image.shape[1]}x{image.shape[0]} "
                              f"where {self._shape[1]}x{self._shape[0]} was set")
        return image

    def _grey(self, raw: np.ndarray) -> np.ndarray:
        """The luma of one raw V4L2 buffer of the format asked for (CameraError naming the
        format it holds instead). OpenCV hands YUYV as (height, width, 2) or, in older
        versions, as one row of bytes; MJPEG as one row of the JPEG's bytes."""
        height, width = self._shape
        flat = raw.reshape(-1)
        is_jpeg = flat[:2].tobytes() == JPEG_START
        if self._fourcc == "YUYV":
            if flat.size == 2 * height * width:  # Y0 U Y1 V: the luma is every other byte
                return np.ascontiguousarray(flat.reshape(height, width, 2)[:, :, 0])
            held = "a JPEG frame (MJPG)" if is_jpeg else f"{flat.size} bytes"
            raise self._other_format(f"{held} where a YUYV frame is {2 * height * width} bytes")
        if not is_jpeg:
            held = ("a raw buffer of 2 bytes per pixel (YUYV)"
                    if flat.size == 2 * height * width else f"{flat.size} bytes that are no JPEG")
            raise self._other_format(held)
        image = cv2.imdecode(flat, cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise CameraError(f"camera {self._name} ({self._device_id}): a JPEG frame of "
                              f"{flat.size} bytes could not be decoded (cut short on the USB "
                              "link?); check the cable, or use a lower frame rate or size")
        return np.asarray(image)

    def _other_format(self, held: str) -> CameraError:
        """The error for a buffer that is not of the format asked for."""
        return CameraError(
            f"camera {self._name} ({self._device_id}): asked for {self._fourcc}, it delivered "
            f"{held}: the driver changed the format without saying so; choose a mode the "
            "camera lists (`v4l2-ctl --list-formats-ext`) and set fourcc to its format")

    def close(self) -> None:
        self._cap.release()


def _fourcc_text(code: int) -> str:
    return "".join(chr((code >> 8 * i) & 0xFF) for i in range(4)) if code > 0 else "(none)"

