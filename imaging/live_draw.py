"""A live map drawn over its camera frame: what the operator's page and the video file show.

The level (dB re the map's peak, NaN below the dynamic range, `LiveImager.level_image`) is
coloured with a perceptual colour map (OpenCV's inferno) and blended over the camera image
where it is defined, more opaque the louder; a cross marks the peak and a line of text names
the band, the method and the range, so that a still of the video says what it shows.
"""

from __future__ import annotations

import cv2
import numpy as np

MAX_ALPHA = 0.65
"""Opacity of the map at its peak (0 at the bottom of the dynamic range)."""


def _bgr(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The camera image as BGR uint8 at size (width, height)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if (img.shape[1], img.shape[0]) != size:
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    return img


def draw_live_frame(image: np.ndarray, level_db: np.ndarray, dynamic_range_db: float,
                    peak_px: np.ndarray | None = None, caption: str = "",
                    image_scale: float = 1.0) -> np.ndarray:
    """The BGR uint8 frame (h, w, 3): `image` (grey or BGR, the camera's) with the map over it.

    Args:
        image: the camera frame.
        level_db: (h, w) level at every pixel of the output (its size sets the output's).
        dynamic_range_db: the level's range (the bottom of it is transparent).
        peak_px: the peak's pixel in the full-resolution camera image, or None.
        caption: drawn at the top left.
        image_scale: the output's size relative to the camera's (for peak_px).
    """
    h, w = level_db.shape
    out = _bgr(image, (w, h))
    defined = np.isfinite(level_db)
    strength = np.where(defined, 1.0 + level_db / dynamic_range_db, 0.0).clip(0.0, 1.0)
    colours = cv2.applyColorMap((255 * strength).astype(np.uint8), cv2.COLORMAP_INFERNO)
    alpha = (MAX_ALPHA * strength)[:, :, None]
    out = (out * (1.0 - alpha) + colours * alpha).astype(np.uint8)
    if peak_px is not None and np.all(np.isfinite(peak_px)):
        centre = tuple(round(float(v)) for v in np.asarray(peak_px) * image_scale)
        cv2.drawMarker(out, centre, (255, 255, 255), cv2.MARKER_CROSS,
                       max(9, w // 40), 2)
    if caption:
        scale = max(0.4, w / 1600)
        cv2.putText(out, caption, (8, int(24 * scale / 0.6)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    (255, 255, 255), max(1, round(2 * scale)), cv2.LINE_AA)
    return out
