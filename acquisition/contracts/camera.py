"""The camera interface the capture sequencer drives (real V4L2 cameras and simulated ones)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np

PixelFormat = Literal["MJPG", "YUYV"]
"""The V4L2 pixel formats (FOURCC) a real camera may be asked for: MJPG, the JPEG frames most
UVC webcams deliver at their larger sizes, and YUYV, uncompressed 4:2:2 (two bytes per pixel,
luma first), what UVC and many industrial cameras deliver at their smaller sizes or lower
rates. `v4l2-ctl --list-formats-ext` lists a camera's modes."""


class CameraError(RuntimeError):
    """A camera failed: it could not be opened, returned no frame, or was unplugged."""


class CameraTimeoutError(CameraError):
    """The camera returned no fresh frame within the allowed time."""


@dataclass(frozen=True)
class Frame:
    """One image from a camera.

    Attributes:
        image: uint8 array, (height, width) for grey or (height, width, 3) for BGR colour.
        timestamp_s: when the frame was taken, seconds on the monotonic clock of the host.
        camera: the name of the camera that took it ("cam0", ...).
    """

    image: np.ndarray
    timestamp_s: float
    camera: str


@runtime_checkable
class Camera(Protocol):
    """One camera of the array."""

    @property
    def name(self) -> str:
        """Short name used in file names and results: "cam0", "cam1", ..."""

    @property
    def device_id(self) -> str:
        """A stable identity of the physical device (serial or by-id path)."""

    def grab(self, timeout_s: float = 2.0) -> Frame:
        """Return a fresh frame taken after this call began (CameraTimeoutError if none)."""

    def close(self) -> None:
        """Release the device."""


@runtime_checkable
class PreviewSource(Protocol):
    """A camera that offers a cheaper look than `grab` for a live preview (optional: the
    daemon grabs a frame from a camera without it and shrinks it)."""

    def preview(self, max_width: int, timeout_s: float = 2.0) -> Frame:
        """A frame at most `max_width` pixels wide, showing what `grab` would now see; it is
        not a frame of the capture (it neither counts as one nor changes what one records)."""
