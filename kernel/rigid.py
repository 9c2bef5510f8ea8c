"""Rigid transforms, the one implementation micam has: rotation vectors and matrices, the
transform type, the SO(3) Jacobians of the fits, and the least-squares rigid fit (Kabsch).

The simulated world (sim.geometry), the calibration (cameras, speakers, solver, joint fit,
Cramer-Rao bounds) and the imaging geometry all use these, so a frame convention is written
once: x_to = R x_from + t, R = exp([rotvec]x) (OpenCV's Rodrigues convention), metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation


def rotation_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices of rotation vectors (..., 3) (axis times angle, radians).

    scipy's quaternion path: exact to rounding near a half turn, where cv2.Rodrigues loses
    about 1e-4 rad."""
    v = np.array(rotvec, dtype=np.float64)  # scipy needs a writable, contiguous buffer
    return Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix().reshape(*v.shape[:-1], 3, 3)


def rotvec_from_rotation(R: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors (radians) of rotation matrices (..., 3, 3)."""
    m = np.asarray(R, dtype=np.float64)
    return Rotation.from_matrix(m.reshape(-1, 3, 3)).as_rotvec().reshape(*m.shape[:-2], 3)


@dataclass(frozen=True)
class RigidTransform:
    """x_to = R @ x_from + t (R a rotation matrix, t in metres): the one transform type.

    The records that hold a transform (a camera's from camera 0, a board pose, a camera view
    of imaging) keep one of these in a field named for its direction (`cam0_to_cam`,
    `rig_to_cam0`) and apply, invert and compose it only through these methods.

    A transform made by `from_rotvec` keeps the rotation vector it was given: `rotvec` returns
    it bit for bit and on its branch (near a half turn r and r (1 - 2 pi / |r|) are the same
    rotation), so a fitted parameter vector survives the round trip and a covariance of
    (rotvec, t) stays the covariance of the transform's own parameters. Otherwise `rotvec` is
    computed from R (angle in [0, pi]). `given_rotvec` is that vector; only `from_rotvec`
    sets it.
    """

    R: np.ndarray
    t: np.ndarray
    given_rotvec: np.ndarray | None = field(default=None, repr=False, compare=False)

    @staticmethod
    def identity() -> RigidTransform:
        return RigidTransform(np.eye(3), np.zeros(3))

    @staticmethod
    def from_rotvec(rotvec: np.ndarray, t: np.ndarray) -> RigidTransform:
        """The transform of a rotation vector (radians) and a translation (3,), metres."""
        rotvec = np.array(rotvec, dtype=np.float64)
        return RigidTransform(rotation_from_rotvec(rotvec), np.asarray(t, dtype=np.float64),
                              rotvec)

    @property
    def rotvec(self) -> np.ndarray:
        """(3,) rotation vector, radians: the one given to `from_rotvec`, or R's."""
        return self.given_rotvec if self.given_rotvec is not None else rotvec_from_rotation(self.R)

    @property
    def params(self) -> np.ndarray:
        """(6,) (rotvec, t): the parameters a covariance of the transform is written in."""
        return np.concatenate([self.rotvec, self.t])

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform points of shape (..., 3)."""
        return np.asarray(points) @ self.R.T + self.t

    def inverse_apply(self, points: np.ndarray) -> np.ndarray:
        """Points (..., 3) of the `to` frame into the `from` frame: R^T (x - t), which is
        `inverse().apply(points)` to rounding without forming the inverse."""
        return (np.asarray(points) - self.t) @ self.R

    def compose(self, inner: RigidTransform) -> RigidTransform:
        """The transform that applies `inner` first, then self."""
        return RigidTransform(self.R @ inner.R, self.R @ inner.t + self.t)

    def inverse_compose(self, inner: RigidTransform) -> RigidTransform:
        """The transform that applies `inner` first, then the inverse of self:
        (R^T R_inner, R^T (t_inner - t)), `inverse().compose(inner)` to rounding without
        forming the inverse (a board pose seen by one camera carried into camera 0's frame)."""
        return RigidTransform(self.R.T @ inner.R, self.inverse_apply(inner.t))

    def inverse(self) -> RigidTransform:
        return RigidTransform(self.R.T, -self.R.T @ self.t)

    def to_json(self) -> dict:
        return {"rotvec": self.rotvec.tolist(), "t_m": np.asarray(self.t).tolist()}


def skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices [v]x, so that [v]x w = v x w."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def right_jacobian(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) right Jacobian J_r of SO(3): R(v + dv) ~ R(v) exp([J_r(v) dv]x).

    J_r(v) = I - (1 - cos t) / t^2 [v]x + (t - sin t) / t^3 [v]x^2, t = |v| (series near 0).
    It gives d(R(v) B)/dv = -R(v) [B]x J_r(v), the rotation part of the analytic Jacobian.
    """
    v = np.asarray(v, dtype=float)
    t = np.linalg.norm(v, axis=-1)[..., None, None]
    small = t < 1e-4
    ts = np.where(small, 1.0, t)
    a = np.where(small, 0.5 - t**2 / 24.0, (1.0 - np.cos(ts)) / ts**2)
    b = np.where(small, 1.0 / 6.0 - t**2 / 120.0, (ts - np.sin(ts)) / ts**3)
    K = skew(v)
    return np.eye(3) - a * K + b * (K @ K)


def rotated_point_jacobian(rotvec: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n, 3, 3) d(R(rotvec) p)/d(rotvec) for rotvec (n, 3) and points (n, 3)."""
    rotvec = np.array(rotvec, dtype=float)
    return -rotation_from_rotvec(rotvec) @ skew(points) @ right_jacobian(rotvec)


def kabsch(a: np.ndarray, b: np.ndarray) -> RigidTransform:
    """The transform (R, t) minimising sum |R a_i + t - b_i|^2 (points (n, 3)): a's frame to
    b's."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return RigidTransform(R, cb - R @ ca)
