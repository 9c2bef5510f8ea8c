"""A camera's corner noise, estimated from the reprojection residuals of its board views.

Why from the data: the corners' scatter depends on the sensor's noise, the blur (a defocused
or moving board), the size of the squares in the image and the compression, none of which
the calibration is told; it weights the views against each other, gives the intrinsics and
the poses their covariances and the joint fit its corner weights.

Why the degrees of freedom: a fit absorbs part of the noise. A view's residuals have
2 n - p_i degrees of freedom, p_i the parameters they determine (their hat matrix's trace):
its pose's 6 and its share of the camera's 9 intrinsics. The plain RMS of the residuals
underestimates the noise by sqrt(1 - p / n) (a 54-corner view by 5.7 % for its pose alone).

Per camera, and per view where the data say a view differs: the pooled estimate over the
camera's views, except for views whose own estimate lies outside the chi-square interval
(`DIFFERENT_VIEW_PROBABILITY`) the pooled noise allows (a blurred or distant view), which
keep their own and are left out of the pool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

DIFFERENT_VIEW_PROBABILITY = 1e-3
"""Two-sided probability below which a view's residuals are taken to have a noise of their
own: a session's 90 views then give one to a view of the pooled noise in about one session
in eleven (harmless: its own estimate is unbiased, only noisier)."""
MAX_ROUNDS = 5
"""Rounds of pooling and testing at most (the set of views with their own settles in two or
three)."""


@dataclass(frozen=True)
class CornerNoise:
    """A camera's corner noise per pixel coordinate.

    Attributes:
        sigma_px: pooled over the views whose noise agrees, pixels (per coordinate).
        n_corners: corners of those views.
        dof: the pooled estimate's degrees of freedom (coordinates less absorbed parameters).
        view_sigma_px: (n_view,) each view's sigma, pixels: `sigma_px`, or its own where
            `own`.
        own: (n_view,) the views whose noise differs from the pool's.
    """

    sigma_px: float
    n_corners: int
    dof: float
    view_sigma_px: np.ndarray
    own: np.ndarray

    @property
    def std_px(self) -> float:
        """Standard deviation of `sigma_px` itself, pixels (sigma / sqrt(2 dof))."""
        return self.sigma_px / np.sqrt(2.0 * self.dof)


def estimate_corner_noise(sum_sq_px2: np.ndarray, n_corners: np.ndarray,
                          absorbed: np.ndarray) -> CornerNoise:
    """The corner noise of one camera's views.

    Args:
        sum_sq_px2: (n_view,) sum of the squared residuals of each view's corners, px^2.
        n_corners: (n_view,) corners of each view (2 coordinates each).
        absorbed: (n_view,) parameters each view's residuals determine (the trace of their
            block of the hat matrix: 6 for the pose plus the view's share of the intrinsics).

    Raises:
        ValueError: no view with more coordinates than absorbed parameters.
    """
    sum_sq = np.asarray(sum_sq_px2, float)
    n = np.asarray(n_corners, int)
    dof = 2.0 * n - np.asarray(absorbed, float)
    if not np.any(dof > 0):
        raise ValueError("corner noise: no view has more coordinates than fitted parameters")
    usable = dof > 0
    own = np.zeros(sum_sq.size, dtype=bool)
    view_var = np.where(usable, sum_sq / np.where(usable, dof, 1.0), np.nan)
    for _ in range(MAX_ROUNDS):
        pool = usable & ~own
        var = float(sum_sq[pool].sum() / dof[pool].sum())
        low = chi2.ppf(DIFFERENT_VIEW_PROBABILITY / 2, np.maximum(dof, 1.0)) / dof
        high = chi2.isf(DIFFERENT_VIEW_PROBABILITY / 2, np.maximum(dof, 1.0)) / dof
        ratio = view_var / var
        now = usable & ((ratio < low) | (ratio > high))
        if np.array_equal(now, own) or now.all():
            break
        own = now
    pool = usable & ~own
    var = float(sum_sq[pool].sum() / dof[pool].sum())
    view_sigma = np.sqrt(np.where(own, view_var, var))
    return CornerNoise(float(np.sqrt(var)), int(n[pool].sum()), float(dof[pool].sum()),
                       view_sigma, own)
