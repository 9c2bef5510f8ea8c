"""A scan plane facing a camera at a chosen depth, and the map-to-pixel table of that camera.

The live view (`live`) beamforms on the plane z = depth of a camera's own frame (a wall, a
machine, a person at a known distance), over the rectangle of that plane the camera sees, on
a fixed n_u x n_v grid (u along the camera's x, v along its y). Since the grid and the camera
never change during a live run, the pixel-to-grid table of `overlay.map_to_image` (undistort
every pixel, intersect its ray with the plane) is computed once here (`ImageMapper`), and each
frame costs one `cv2.remap` of the (n_u, n_v) map.
"""

from __future__ import annotations

import cv2
import numpy as np

from .geometry import CameraView
from .grid import PlaneGrid
from .overlay import _rays_on_plane

BORDER_SAMPLES = 65
"""Points per image edge whose rays bound the plane's visible rectangle."""


def depth_plane_grid(camera: CameraView, depth_m: float, shape: tuple[int, int] = (101, 101)
                     ) -> PlaneGrid:
    """The grid of shape (n_u, n_v) on the plane z = depth_m of `camera`'s frame that covers
    everything the camera sees of it (the bounding rectangle of the image border's rays, with
    the lens distortion), points in the camera-0 frame."""
    if not depth_m > 0:
        raise ValueError(f"the scan plane's depth {depth_m} m must be positive (in front of "
                         f"camera {camera.name})")
    n_u, n_v = shape
    if n_u < 2 or n_v < 2:
        raise ValueError(f"a live grid needs at least 2 x 2 points, got {n_u} x {n_v}")
    w, h = camera.width, camera.height
    edge = np.linspace(0.0, 1.0, BORDER_SAMPLES)
    border = np.vstack([np.column_stack([edge * (w - 1), np.zeros_like(edge)]),
                        np.column_stack([edge * (w - 1), np.full_like(edge, h - 1)]),
                        np.column_stack([np.zeros_like(edge), edge * (h - 1)]),
                        np.column_stack([np.full_like(edge, w - 1), edge * (h - 1)])])
    rays = cv2.undistortPoints(border.reshape(-1, 1, 2), camera.K, camera.dist).reshape(-1, 2)
    lo, hi = rays.min(axis=0) * depth_m, rays.max(axis=0) * depth_m
    # camera frame -> camera-0 frame: x0 = R^T (x - t)
    origin = camera.R.T @ (np.array([0.0, 0.0, depth_m]) - camera.t)
    return PlaneGrid(origin, camera.R[0].copy(), camera.R[1].copy(),
                     np.linspace(lo[0], hi[0], n_u), np.linspace(lo[1], hi[1], n_v))


class ImageMapper:
    """Resamples maps on one grid at every pixel of one camera (bilinear; NaN where a
    pixel's ray misses the grid), with the table computed once (module docstring).

    Args:
        grid: the scan grid (camera-0 frame).
        camera: the camera whose pixels are filled.
        scale: the output image's size relative to the camera's (0.5: half width and height;
            the pixel centres are those of the downscaled image).
    """

    def __init__(self, grid: PlaneGrid, camera: CameraView, scale: float = 1.0) -> None:
        if not 0 < scale <= 1:
            raise ValueError(f"image scale {scale} must be in (0, 1]")
        self.grid = grid
        self.width = max(1, round(camera.width * scale))
        self.height = max(1, round(camera.height * scale))
        cols, rows = np.meshgrid((np.arange(self.width) + 0.5) / scale - 0.5,
                                 (np.arange(self.height) + 0.5) / scale - 0.5)
        pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
        points, hit = _rays_on_plane(camera, pixels, grid.origin_m, grid.normal)
        uv = grid.coordinates(points)
        du, dv = grid.spacing()
        fi = (uv[:, 0] - grid.u_m[0]) / du
        fj = (uv[:, 1] - grid.v_m[0]) / dv
        fi[~hit] = -1e6
        # remap samples src[map_y, map_x]: rows are u (i), columns v (j)
        self._map_x = fj.reshape(self.height, self.width).astype(np.float32)
        self._map_y = fi.reshape(self.height, self.width).astype(np.float32)

    def to_image(self, values: np.ndarray) -> np.ndarray:
        """The map (G,) or (n_u, n_v) at every pixel: (height, width) float32."""
        values = np.asarray(values, dtype=np.float32)
        if values.size != self.grid.size:
            raise ValueError(f"the map has {values.size} values but the grid "
                             f"{self.grid.size} points")
        return cv2.remap(values.reshape(self.grid.shape), self._map_x, self._map_y,
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=float("nan"))
