"""Acoustic maps drawn on camera images (paper section III and VI-A).

A map computed on a `PlaneGrid` in the camera-0 frame is resampled at every pixel of a camera:
each pixel is undistorted with the camera's intrinsics and distortion (OpenCV model), its ray
is intersected with the scan plane, and the map is interpolated bilinearly there. This is
exact for any camera pose, so a map on the rig plane registers on the image of a camera away
from the array centre too. `field_of_view_grid` makes the scan surface cover everything a
camera sees of the rig plane, so that a map fills the image (`calibration.figures.maps`
draws it).
"""

from __future__ import annotations

import cv2
import numpy as np

from calibration.errors import CalibrationInputError

from .cleansc import CleanScResult, Component
from .geometry import BoardPose, CameraView
from .grid import PlaneGrid

MAX_VIEW_POINTS = 120_000
"""Largest grid `field_of_view_grid` makes (CLEAN-SC's time per band grows with it:
benchmarks/bench_imaging.py); beyond it the spacing grows."""
MAX_VIEW_EXTENT_M = 3.0
"""How far from the rig's centre a field-of-view grid reaches at most (a plane seen at a
grazing angle reaches the horizon)."""


def _rays_on_plane(camera: CameraView, pixels: np.ndarray, origin_m: np.ndarray,
                   normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the rays of `pixels` (N, 2) of `camera` meet the plane through origin_m with
    `normal` (camera-0 frame): points (N, 3), and whether each ray meets it in front of the
    camera (N,). Pixels are undistorted with the camera's intrinsics and distortion."""
    rays = cv2.undistortPoints(pixels.reshape(-1, 1, 2).astype(np.float64), camera.K,
                               camera.dist).reshape(-1, 2)
    cam_to_cam0 = camera.cam0_to_cam.inverse()
    centre = cam_to_cam0.t
    direction = np.column_stack([rays, np.ones(len(rays))]) @ cam_to_cam0.R.T  # rows: R^T d
    denom = direction @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((origin_m - centre) @ normal) / denom
    hit = np.isfinite(s) & (s > 0)
    return centre + np.where(hit, s, 0.0)[:, None] * direction, hit


class ImageMapper:
    """Resamples maps on one grid at every pixel of one camera (bilinear; NaN where a pixel's
    ray misses the grid: outside it, or the plane is behind the camera). The pixel-to-grid
    table is computed once, so a live view pays one `cv2.remap` per frame.

    Args:
        grid: the scan grid (camera-0 frame).
        camera: the camera whose pixels are filled.
        scale: the output image's size relative to the camera's (0.5: half width and height;
            its pixel centres are those of the downscaled image).
    """

    def __init__(self, grid: PlaneGrid, camera: CameraView, scale: float = 1.0) -> None:
        if not 0 < scale <= 1:
            raise CalibrationInputError(f"image scale {scale} must be in (0, 1]")
        self.grid = grid
        self.width = max(1, round(camera.width * scale))
        self.height = max(1, round(camera.height * scale))
        cols, rows = np.meshgrid((np.arange(self.width) + 0.5) / scale - 0.5,
                                 (np.arange(self.height) + 0.5) / scale - 0.5)
        pixels = np.stack([cols.ravel(), rows.ravel()], axis=1)
        points, hit = _rays_on_plane(camera, pixels, grid.origin_m, grid.normal)
        uv = grid.coordinates(points)
        du, dv = grid.spacing()
        fi = (uv[:, 0] - grid.u_m[0]) / du if du else np.zeros(len(uv))
        fj = (uv[:, 1] - grid.v_m[0]) / dv if dv else np.zeros(len(uv))
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
                         interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=float("nan"))


def map_to_image(values: np.ndarray, grid: PlaneGrid, camera: CameraView) -> np.ndarray:
    """The map resampled at every pixel of `camera`: (height, width) float64, NaN where the
    pixel's ray misses the grid (outside it, or the plane is behind the camera)."""
    return ImageMapper(grid, camera).to_image(values).astype(np.float64)


def field_of_view_grid(camera: CameraView, pose: BoardPose, z_rig_m: float, spacing_m: float,
                       max_points: int = MAX_VIEW_POINTS) -> PlaneGrid:
    """The rig plane Z = z_rig_m of a pose over all that `camera` sees of it: the rays of
    the image's border meet the plane, and the grid spans their rig coordinates (at most
    `MAX_VIEW_EXTENT_M` from the rig's origin), every spacing_m, or coarser if the grid would
    exceed max_points points. Maps on it fill the whole image instead of ending at the
    rig's plate."""
    if spacing_m <= 0:
        raise CalibrationInputError(f"grid spacing {spacing_m} m must be positive")
    w, h = camera.width, camera.height
    edge = np.linspace(0.0, 1.0, 65)
    border = np.vstack([np.column_stack([edge * (w - 1), np.zeros_like(edge)]),
                        np.column_stack([edge * (w - 1), np.full_like(edge, h - 1)]),
                        np.column_stack([np.zeros_like(edge), edge * (h - 1)]),
                        np.column_stack([np.full_like(edge, w - 1), edge * (h - 1)])])
    rig_to_cam0 = pose.rig_to_cam0
    origin = rig_to_cam0.apply(np.array([0.0, 0.0, z_rig_m]))
    points, hit = _rays_on_plane(camera, border, origin, rig_to_cam0.R[:, 2])
    if hit.sum() < 3:
        raise CalibrationInputError(
            f"{camera.name} does not see the rig plane of pose {pose.index}")
    rig_xy = rig_to_cam0.inverse_apply(points[hit])[:, :2]
    if not hit.all():  # part of the border looks past the plane's horizon
        rig_xy = np.vstack([rig_xy, [[-MAX_VIEW_EXTENT_M] * 2, [MAX_VIEW_EXTENT_M] * 2]])
    lo = np.maximum(rig_xy.min(axis=0), -MAX_VIEW_EXTENT_M)
    hi = np.minimum(rig_xy.max(axis=0), MAX_VIEW_EXTENT_M)
    # The smallest spacing s with (Lu / s + 1)(Lv / s + 1) <= max_points.
    lu, lv = hi - lo
    k = max_points - 1
    spacing = max(spacing_m, float((lu + lv + np.sqrt((lu + lv) ** 2 + 4 * k * lu * lv))
                                   / (2 * k)) * (1 + 1e-9))
    return PlaneGrid.on_rig(rig_to_cam0, (lo[0], hi[0]), (lo[1], hi[1]), z_rig_m, spacing)


def clean_sources(result: CleanScResult, grid: PlaneGrid) -> tuple[np.ndarray, np.ndarray]:
    """The CLEAN-SC map as point sources to draw: one per grid node that received components,
    with their summed power (the clean map's value there) at the sub-grid peak of the
    strongest of them. Returns points (K, 3) and powers (K,), strongest first."""
    strongest: dict[int, Component] = {}
    for c in result.components:
        if c.index not in strongest or c.power > strongest[c.index].power:
            strongest[c.index] = c
    nodes = sorted(strongest, key=lambda i: -result.clean_map[i])
    points = []
    for i in nodes:
        subgrid = strongest[i].subgrid
        points.append(grid.points[i] if subgrid is None else grid.at_index(*subgrid))
    return (np.array(points).reshape(-1, 3),
            np.array([result.clean_map[i] for i in nodes], dtype=np.float64))
