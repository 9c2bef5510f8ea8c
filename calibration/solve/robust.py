"""The robust fitting helpers the solver, the joint fit and the plausibility checks share."""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_factor, cho_solve

MAD_TO_SIGMA = 1.4826
"""A Gaussian's standard deviation over its median absolute deviation from 0."""


def robust_sigma(residuals: np.ndarray, floor: float = 0.0) -> float:
    """1.4826 x median |r|: the sigma of the Gaussian part of residuals, outliers ignored; at
    least `floor` (in the residuals' units), so that a perfect fit still weighs something.
    ValueError for no residuals (the caller knows what that means for it)."""
    r = np.asarray(residuals)
    if r.size == 0:
        raise ValueError("a robust sigma needs at least one residual")
    return max(MAD_TO_SIGMA * float(np.median(np.abs(r))), floor)


def inverse_normal(A: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric normal matrix J^T J, scaled to unit diagonal first (its columns
    may span pixels, metres and seconds); the pseudo-inverse if it is singular."""
    scale = np.sqrt(np.maximum(np.diag(A), 1e-300))
    A_s = A / scale / scale[:, None]
    try:
        inv = cho_solve(cho_factor(A_s), np.eye(A.shape[0]))
    except np.linalg.LinAlgError:
        inv = np.linalg.pinv(A_s)
    return inv / scale / scale[:, None]
