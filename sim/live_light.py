"""Camera images of a live scene: a room's back wall with the sources where they are.

Not a photograph, but what the live view needs to be judged by eye and by test: the wall is a
fixed pattern of tiles (so that the image registers visibly), and each source is drawn as a
speaker (a dark disc of `SPEAKER_RADIUS_M` with a light rim) centred on the exact projection
of its acoustic centre through the camera's intrinsics and distortion (`CameraModel.project`),
with sensor noise.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from .geometry import CameraModel

SPEAKER_RADIUS_M = 0.04
"""Radius of the disc a source is drawn as."""
TILE_PX = 80
"""Side of the wall's tiles, pixels."""
NOISE_FIELDS = 8
"""Sensor noise is drawn from this many fields kept per image size and noise level (a fresh
field per frame costs more than the rest of the picture)."""


@lru_cache(maxsize=8)
def _wall(width: int, height: int) -> np.ndarray:
    """The background (height, width) uint8: a soft vertical gradient with tile joints."""
    rows = np.linspace(150.0, 95.0, height)[:, None]
    wall = np.repeat(rows, width, axis=1)
    wall[::TILE_PX, :] -= 25.0
    wall[:, ::TILE_PX] -= 25.0
    blurred = np.asarray(cv2.GaussianBlur(wall, (0, 0), 1.0), dtype=np.float64)
    out = blurred.clip(0, 255).astype(np.uint8)
    out.flags.writeable = False
    return out


_NOISE: dict[tuple[int, int, float], list[np.ndarray]] = {}


def _noise_field(width: int, height: int, noise_grey: float, rng: np.random.Generator
                 ) -> np.ndarray:
    """A field (height, width) int16 of Gaussian sensor noise (grey levels): a new one for
    each of the first NOISE_FIELDS frames of a size and level, then one of those again."""
    fields = _NOISE.setdefault((width, height, noise_grey), [])
    if len(fields) < NOISE_FIELDS:
        fields.append(np.rint(rng.normal(0.0, noise_grey, (height, width))).astype(np.int16))
        return fields[-1]
    return fields[int(rng.integers(NOISE_FIELDS))]


def render_scene_image(model: CameraModel, sources_m: np.ndarray, rng: np.random.Generator,
                       noise_grey: float = 2.0) -> np.ndarray:
    """The grey image (height, width) uint8 camera `model` takes of sources at sources_m
    (K, 3), camera-0 frame."""
    image = _wall(model.width, model.height).copy()
    points = np.asarray(sources_m, dtype=np.float64).reshape(-1, 3)
    in_front = model.in_front(points)
    if np.any(in_front):
        depth = model.cam0_to_cam.apply(points[in_front])[:, 2]
        for (u, v), z in zip(model.project(points[in_front]), depth, strict=True):
            radius = max(2, round(model.K[0, 0] * SPEAKER_RADIUS_M / z))
            centre = (round(u * 16), round(v * 16))  # 4 fractional bits: sub-pixel centres
            cv2.circle(image, centre, radius * 16, 215, -1, cv2.LINE_AA, 4)
            cv2.circle(image, centre, round(0.8 * radius * 16), 35, -1, cv2.LINE_AA, 4)
    if noise_grey > 0:
        noisy = _noise_field(model.width, model.height, float(noise_grey), rng) + image
        image = np.clip(noisy, 0, 255).astype(np.uint8)
    return image
