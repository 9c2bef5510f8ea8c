"""Scan surfaces: regular grids on planes placed anywhere in space.

A `PlaneGrid` is the set of points origin + u_i * u_axis + v_j * v_axis with u_i, v_j on regular
grids. It covers the two cases of paper section VI: a 2-D plane in front of the array
(`xy_plane`) and the 3-D surface through the rig's speakers given by a board pose (`on_rig`),
whose points are in the camera-0 frame so that the map registers on any camera's image.
Points are ordered with u slowest (flat index i * n_v + j, Acoular's `RectGrid` order); a map
reshaped to `shape` is indexed [i, j].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import CalibrationInputError
from kernel.rigid import RigidTransform


def _axis(n_points: int, lo: float, hi: float, spacing: float) -> np.ndarray:
    if n_points < 1:
        raise ValueError("a grid axis needs at least one point")
    return lo + spacing * np.arange(n_points) if n_points > 1 else np.array([(lo + hi) / 2])


@dataclass(frozen=True)
class PlaneGrid:
    """A regular grid on a plane.

    Attributes:
        origin_m: (3,) the point with u = v = 0.
        u_axis, v_axis: (3,) orthonormal in-plane directions.
        u_m, v_m: grid coordinates along each axis, metres, increasing and evenly spaced.
    """

    origin_m: np.ndarray
    u_axis: np.ndarray
    v_axis: np.ndarray
    u_m: np.ndarray
    v_m: np.ndarray

    def __post_init__(self) -> None:
        u, v = np.asarray(self.u_axis, float), np.asarray(self.v_axis, float)
        if u.shape != (3,) or v.shape != (3,) or np.asarray(self.origin_m).shape != (3,):
            raise ValueError("origin and axes of a plane grid must be 3-vectors")
        if abs(np.linalg.norm(u) - 1) > 1e-9 or abs(np.linalg.norm(v) - 1) > 1e-9 or abs(
                u @ v) > 1e-9:
            raise ValueError("the axes of a plane grid must be orthonormal")
        for name, c in (("u", self.u_m), ("v", self.v_m)):
            c = np.asarray(c)
            if c.ndim != 1 or c.size == 0 or (c.size > 1 and np.any(np.diff(c) <= 0)):
                raise ValueError(f"{name} coordinates must be a non-empty increasing 1-D array")

    @staticmethod
    def on_plane(origin_m: np.ndarray, u_axis: np.ndarray, v_axis: np.ndarray,
                 u_range: tuple[float, float], v_range: tuple[float, float], spacing_m: float
                 ) -> PlaneGrid:
        """Points every spacing_m from the low end of each range up to its high end."""
        if spacing_m <= 0:
            raise CalibrationInputError(f"grid spacing {spacing_m} m must be positive")
        (u0, u1), (v0, v1) = u_range, v_range
        if u1 < u0 or v1 < v0:
            raise CalibrationInputError(f"empty grid ranges {u_range}, {v_range}")
        nu = int(np.floor((u1 - u0) / spacing_m + 1e-9)) + 1
        nv = int(np.floor((v1 - v0) / spacing_m + 1e-9)) + 1
        return PlaneGrid(np.asarray(origin_m, float), np.asarray(u_axis, float),
                         np.asarray(v_axis, float), _axis(nu, u0, u1, spacing_m),
                         _axis(nv, v0, v1, spacing_m))

    @staticmethod
    def xy_plane(x_range: tuple[float, float], y_range: tuple[float, float], z_m: float,
                 spacing_m: float) -> PlaneGrid:
        """A plane z = z_m of the frame (a classic 2-D scan plane in front of the array)."""
        return PlaneGrid.on_plane(np.array([0.0, 0.0, z_m]), np.array([1.0, 0.0, 0.0]),
                                  np.array([0.0, 1.0, 0.0]), x_range, y_range, spacing_m)

    @staticmethod
    def on_rig(rig_to_frame: RigidTransform, x_range: tuple[float, float],
               y_range: tuple[float, float], z_rig_m: float, spacing_m: float) -> PlaneGrid:
        """The plane Z = z_rig_m of the rig (board) frame, seen through a board pose
        x_frame = R x_rig + t (paper VI-A: z_rig_m = -2.5 mm passes through the speakers)."""
        R = rig_to_frame.R
        return PlaneGrid.on_plane(rig_to_frame.apply(np.array([0.0, 0.0, z_rig_m])),
                                  R[:, 0], R[:, 1], x_range, y_range, spacing_m)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(np.size(self.u_m)), int(np.size(self.v_m)))

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.u_axis, self.v_axis)

    def spacing(self) -> tuple[float, float]:
        """Grid spacing along u and v (0 for a single-point axis)."""
        du = float(self.u_m[1] - self.u_m[0]) if self.shape[0] > 1 else 0.0
        dv = float(self.v_m[1] - self.v_m[0]) if self.shape[1] > 1 else 0.0
        return du, dv

    def point(self, u_m: np.ndarray | float, v_m: np.ndarray | float) -> np.ndarray:
        """3-D points (..., 3) at plane coordinates (u, v)."""
        u = np.asarray(u_m, float)[..., None]
        v = np.asarray(v_m, float)[..., None]
        return self.origin_m + u * self.u_axis + v * self.v_axis

    @property
    def points(self) -> np.ndarray:
        """(n_u * n_v, 3) scan points, u slowest."""
        uu, vv = np.meshgrid(self.u_m, self.v_m, indexing="ij")
        return self.point(uu.ravel(), vv.ravel())

    def coordinates(self, points_m: np.ndarray) -> np.ndarray:
        """Plane coordinates (..., 2) = (u, v) of points projected onto the plane."""
        d = np.asarray(points_m, float) - self.origin_m
        return np.stack([d @ self.u_axis, d @ self.v_axis], axis=-1)

    def at_index(self, i: float, j: float) -> np.ndarray:
        """The 3-D point at fractional grid index (i, j)."""
        du, dv = self.spacing()
        return self.point(self.u_m[0] + i * du, self.v_m[0] + j * dv)
