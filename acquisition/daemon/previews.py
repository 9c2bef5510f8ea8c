"""Camera previews for an operator's page: small JPEGs with the board's corners drawn on them.

Previews are published as `preview` events, and only while a client has asked for them
(`previews` with a number of seconds; `micam web` asks again every few seconds while a browser
is connected), so a daemon nobody watches spends nothing on them. While the daemon waits for a
step it looks at one camera per turn of its loop, each camera at most `previews.fps` times a
second; while a step is captured it never touches a camera itself, and the images the capture
takes are shown instead (`show`). A look is a quick look (quality.checkerboard_corners on an
image at most QUICK_LOOK_PX wide), never a measurement.
"""

from __future__ import annotations

import base64
import logging
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from acquisition.contracts.camera import Camera, CameraError, PreviewSource
from .config import PreviewConfig
from acquisition.contracts.protocol import PreviewEvent
from ..preview_jpeg import encode_preview
from .quality import QUICK_LOOK_PX, checkerboard_corners

log = logging.getLogger("micam.daemon")


class Previews:
    """Publishes previews of `cameras` while asked to (see the module docstring)."""

    def __init__(self, config: PreviewConfig, cameras: list[Camera], pattern: tuple[int, int],
                 publish: Callable[..., Any], camera_timeout_s: float) -> None:
        self.config = config
        self.cameras = cameras
        self.pattern = pattern
        self._publish = publish
        self._timeout_s = camera_timeout_s
        self._until = 0.0
        self._next_look = {c.name: 0.0 for c in cameras}

    def request(self, seconds: float) -> float:
        """Publish previews for the next `seconds` (0 stops them); the seconds left."""
        self._until = time.monotonic() + seconds
        return self.remaining_s

    @property
    def remaining_s(self) -> float:
        return max(0.0, self._until - time.monotonic())

    def tick(self, capturing: bool) -> None:
        """Look at the camera most overdue, if any is due (never while `capturing`)."""
        if capturing or self.remaining_s <= 0 or not self.cameras:
            return
        now = time.monotonic()
        camera = min(self.cameras, key=lambda c: self._next_look[c.name])
        if self._next_look[camera.name] > now:
            return
        self._next_look[camera.name] = now + 1.0 / self.config.fps
        try:
            if isinstance(camera, PreviewSource):
                image = camera.preview(QUICK_LOOK_PX, self._timeout_s).image
            else:
                image = camera.grab(self._timeout_s).image
        except CameraError as exc:
            log.info("no preview of %s: %s", camera.name, exc)
            return
        self.show(camera.name, image, checkerboard_corners(image, self.pattern), step=None)

    def show(self, camera: str, image: np.ndarray, corners: np.ndarray | None,
             step: str | None) -> None:
        """Publish a preview of `image` (from `camera`, of `step` or of a look) if asked to."""
        if self.remaining_s <= 0:
            return
        jpeg, width, height = encode_preview(image, corners, self.pattern, self.config.width,
                                             self.config.jpeg_quality)
        self._publish(PreviewEvent, camera=camera, step=step, found=corners is not None,
                      width=width, height=height, source_width=image.shape[1],
                      source_height=image.shape[0],
                      jpeg_b64=base64.b64encode(jpeg).decode("ascii"))
