"""Whether a calibration's reported covariance describes its errors against a truth.

The plain figure is the share of microphones whose 3-D error lies inside the 95.4 % ellipsoid
of their own covariance ("within 2 sigma"). In one session it is a poor judge: the
microphones share the errors of the cameras, the metric scale and the rig, so their errors
move together, and the share depends on one draw of that common motion (a shift, a turn and a
scale of the whole array: 7 numbers), however right the covariance.

So the errors are also split into the array's common motion, a similarity transform about its
centroid fitted to them by least squares, judged once by its chi-square under its covariance
(7 degrees of freedom), and the geometry relative to it, judged microphone by microphone
against the covariance of that relative error (both covariances propagated from the full
covariance of all microphones).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

TWO_SIGMA_3D = float(chi2.ppf(0.9545, 3))
"""Squared Mahalanobis distance of the 3-D ellipsoid that holds 95.45 % (2 sigma in 1-D)."""

COMMON_DOF = 7
"""Shift (3), turn (3) and scale (1) of the whole array."""


@dataclass(frozen=True)
class Coverage:
    """How a covariance covers errors (module docstring).

    Attributes:
        within_2_sigma: share of microphones inside their 95.4 % ellipsoid.
        common_chi2: chi-square of the array's common motion (7 degrees of freedom: about 7
            if the covariance is right, beyond 18.5 in 1 % of sessions).
        common_p: the probability of a chi-square at least that large.
        relative_within_2_sigma: share of microphones whose error relative to the common
            motion is inside the 95.4 % ellipsoid of that relative error.
    """

    within_2_sigma: float
    common_chi2: float
    common_p: float
    relative_within_2_sigma: float


def similarity_basis(positions_m: np.ndarray) -> np.ndarray:
    """(3 n, 7) the small motions of n points about their centroid, as columns: shift x, y, z
    (m), turn about x, y, z (rad) and scale (relative)."""
    p = positions_m - positions_m.mean(axis=0)
    n = p.shape[0]
    basis = np.zeros((n, 3, COMMON_DOF))
    basis[:, :, :3] = np.eye(3)
    for axis in range(3):  # d(R p)/d(angle about axis) = e_axis x p
        basis[:, :, 3 + axis] = np.cross(np.eye(3)[axis], p)
    basis[:, :, 6] = p
    return basis.reshape(3 * n, COMMON_DOF)


def coverage(errors_m: np.ndarray, covariance_m2: np.ndarray,
             positions_m: np.ndarray) -> Coverage:
    """How the full covariance (3 n, 3 n) of n microphones covers their errors (n, 3), the
    microphones being at `positions_m` (n, 3). Raises ValueError on shapes that disagree."""
    n = errors_m.shape[0]
    if errors_m.shape != (n, 3) or positions_m.shape != (n, 3) or covariance_m2.shape != (
            3 * n, 3 * n):
        raise ValueError(f"coverage needs (n, 3) errors and positions and a (3n, 3n) "
                         f"covariance; got {errors_m.shape}, {positions_m.shape}, "
                         f"{covariance_m2.shape}")
    blocks = _blocks(covariance_m2, n)
    within = _share_within(errors_m, blocks)
    A = similarity_basis(positions_m)
    A = A / np.linalg.norm(A, axis=0)  # unit columns: shifts, turns and scale comparable
    A_pinv = np.linalg.pinv(A)
    e = errors_m.ravel()
    common = A_pinv @ e
    common_chi2 = float(common @ np.linalg.solve(A_pinv @ covariance_m2 @ A_pinv.T, common))
    projector = np.eye(3 * n) - A @ A_pinv
    relative = (projector @ e).reshape(n, 3)
    relative_cov = projector @ covariance_m2 @ projector.T
    return Coverage(within, common_chi2, float(chi2.sf(common_chi2, COMMON_DOF)),
                    _share_within(relative, _blocks(relative_cov, n)))


def _blocks(covariance: np.ndarray, n: int) -> np.ndarray:
    """(n, 3, 3) the diagonal blocks of a (3 n, 3 n) covariance."""
    index = 3 * np.arange(n)[:, None] + np.arange(3)
    return covariance[index[:, :, None], index[:, None, :]]


def _share_within(errors: np.ndarray, blocks: np.ndarray) -> float:
    d2 = np.einsum("mi,mi->m", errors, np.linalg.solve(blocks, errors[..., None])[..., 0])
    return float(np.mean(d2 < TWO_SIGMA_3D))
