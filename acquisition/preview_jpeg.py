"""A camera image as a small JPEG for a page: shrunk, the board's corners drawn on it.

Shared by the daemon's previews (acquisition.daemon.previews) and live mode's frames
(acquisition.live.mode), which must not import each other's packages.
"""

from __future__ import annotations

import cv2
import numpy as np


def encode_preview(image: np.ndarray, corners: np.ndarray | None, pattern: tuple[int, int],
                   width: int, quality: int) -> tuple[bytes, int, int]:
    """`image` shrunk to at most `width` pixels wide, the `corners` (pixels of `image`) drawn
    on it, as JPEG bytes with the preview's width and height."""
    scale = min(1.0, width / image.shape[1])
    small = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) \
        if scale < 1.0 else image
    if small.ndim == 2:
        small = cv2.cvtColor(small, cv2.COLOR_GRAY2BGR)
    if corners is not None:
        points = (corners * scale).astype(np.float32).reshape(-1, 1, 2)
        cv2.drawChessboardCorners(small, pattern, points, True)  # found: coloured rows
    ok, jpeg = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("OpenCV could not encode the preview as JPEG")
    return jpeg.tobytes(), small.shape[1], small.shape[0]
