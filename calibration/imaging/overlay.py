"""Acoustic maps drawn on camera images (paper section III and VI-A).

A map computed on a `PlaneGrid` in the camera-0 frame is resampled at every pixel of a camera:
each pixel is undistorted with the camera's intrinsics and distortion (OpenCV model), its ray
is intersected with the scan plane, and the map is interpolated bilinearly there. This is
exact for any camera pose, so a map on the rig plane registers on the image of a camera away
from the array centre too. The map is then drawn as a colour layer over the image, showing
levels within a dynamic range in dB below the map's maximum, and written as PNG.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from .geometry import CameraView
from .grid import PlaneGrid


def map_to_image(values: np.ndarray, grid: PlaneGrid, camera: CameraView) -> np.ndarray:
    """The map resampled at every pixel of `camera`: (height, width) float64, NaN where the
    pixel's ray misses the grid (outside it, or the plane is behind the camera)."""
    values = np.asarray(values, dtype=np.float64)
    if values.size != grid.size:
        raise ValueError(f"the map has {values.size} values but the grid {grid.size} points")
    h, w = camera.height, camera.width
    cols, rows = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pixels = np.stack([cols.ravel(), rows.ravel()], axis=1).reshape(-1, 1, 2)
    rays = cv2.undistortPoints(pixels, camera.K, camera.dist).reshape(-1, 2)
    # Ray x = centre + s * direction in the camera-0 frame.
    centre = -camera.R.T @ camera.t
    direction = np.column_stack([rays, np.ones(len(rays))]) @ camera.R  # rows: R^T d
    normal = grid.normal
    denom = direction @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((grid.origin_m - centre) @ normal) / denom
    hit = np.isfinite(s) & (s > 0)
    points = centre + np.where(hit, s, 0.0)[:, None] * direction
    uv = grid.coordinates(points)
    du, dv = grid.spacing()
    fi = (uv[:, 0] - grid.u_m[0]) / du if du else np.zeros(len(uv))
    fj = (uv[:, 1] - grid.v_m[0]) / dv if dv else np.zeros(len(uv))
    fi[~hit] = -1e6
    image = cv2.remap(values.reshape(grid.shape).astype(np.float32),
                      fj.reshape(h, w).astype(np.float32), fi.reshape(h, w).astype(np.float32),
                      interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=float("nan"))
    return image.astype(np.float64)


def spread_components(clean_map: np.ndarray, grid: PlaneGrid, sigma_cells: float = 1.5
                      ) -> np.ndarray:
    """A CLEAN-SC map (point components on grid nodes) convolved with a Gaussian "clean beam"
    of sigma_cells grid cells, so that its sources show as spots; same shape, flat."""
    image = np.asarray(clean_map, dtype=np.float64).reshape(grid.shape)
    size = 2 * int(np.ceil(3 * sigma_cells)) + 1
    return cv2.GaussianBlur(image, (size, size), sigma_cells,
                            borderType=cv2.BORDER_CONSTANT).ravel()


def render_overlay(image: np.ndarray, layer: np.ndarray, dynamic_range_db: float = 15.0,
                   alpha: float = 0.6, colormap: int = cv2.COLORMAP_JET) -> np.ndarray:
    """The image (grey or BGR uint8) with `layer` (same height and width, power values, NaN
    where absent) drawn in colour where it lies within dynamic_range_db of its maximum."""
    if dynamic_range_db <= 0:
        raise ValueError(f"dynamic range {dynamic_range_db} dB must be positive")
    if image.shape[:2] != layer.shape:
        raise ValueError(f"image {image.shape[:2]} and layer {layer.shape} differ in size")
    base = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    finite = np.isfinite(layer) & (layer > 0)
    if not finite.any():
        return base
    with np.errstate(divide="ignore", invalid="ignore"):
        level = 10.0 * np.log10(np.where(finite, layer, np.nan) / np.nanmax(layer[finite]))
    show = finite & (level >= -dynamic_range_db)
    scaled = np.clip((level + dynamic_range_db) / dynamic_range_db, 0, 1)
    colour = cv2.applyColorMap(np.nan_to_num(scaled * 255).astype(np.uint8), colormap)
    blended = cv2.addWeighted(base, 1 - alpha, colour, alpha, 0)
    base[show] = blended[show]
    return base


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an image as PNG atomically (a temporary file renamed into place)."""
    path = Path(path)
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError(f"cannot encode an image of shape {image.shape} as PNG")
    tmp = path.with_name(path.name + ".partial")
    tmp.write_bytes(data.tobytes())
    os.replace(tmp, path)
