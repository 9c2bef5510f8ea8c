"""A scan plane facing a camera at a chosen depth.

The live view (`live`) beamforms on the plane z = depth of a camera's own frame (a wall, a
machine, a person at a known distance), over the rectangle of that plane the camera sees, on
a fixed n_u x n_v grid (u along the camera's x, v along its y); `overlay.ImageMapper` then
draws its maps on that camera's pixels.
"""

from __future__ import annotations

import cv2
import numpy as np

from calibration.errors import CalibrationInputError

from .geometry import CameraView
from .grid import PlaneGrid

BORDER_SAMPLES = 65
"""Points per image edge whose rays bound the plane's visible rectangle."""


def depth_plane_grid(camera: CameraView, depth_m: float, shape: tuple[int, int] = (101, 101)
                     ) -> PlaneGrid:
    """The grid of shape (n_u, n_v) on the plane z = depth_m of `camera`'s frame that covers
    everything the camera sees of it (the bounding rectangle of the image border's rays, with
    the lens distortion), points in the camera-0 frame."""
    if not depth_m > 0:
        raise CalibrationInputError(
            f"the scan plane's depth {depth_m} m must be positive (in front of "
            f"camera {camera.name})")
    n_u, n_v = shape
    if n_u < 2 or n_v < 2:
        raise CalibrationInputError(f"a live grid needs at least 2 x 2 points, got {n_u} x {n_v}")
    w, h = camera.width, camera.height
    edge = np.linspace(0.0, 1.0, BORDER_SAMPLES)
    border = np.vstack([np.column_stack([edge * (w - 1), np.zeros_like(edge)]),
                        np.column_stack([edge * (w - 1), np.full_like(edge, h - 1)]),
                        np.column_stack([np.zeros_like(edge), edge * (h - 1)]),
                        np.column_stack([np.full_like(edge, w - 1), edge * (h - 1)])])
    rays = cv2.undistortPoints(border.reshape(-1, 1, 2), camera.K, camera.dist).reshape(-1, 2)
    lo, hi = rays.min(axis=0) * depth_m, rays.max(axis=0) * depth_m
    cam0_to_cam = camera.cam0_to_cam
    origin = cam0_to_cam.inverse_apply(np.array([0.0, 0.0, depth_m]))
    return PlaneGrid(origin, cam0_to_cam.R[0].copy(), cam0_to_cam.R[1].copy(),
                     np.linspace(lo[0], hi[0], n_u), np.linspace(lo[1], hi[1], n_v))
