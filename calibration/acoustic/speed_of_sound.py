"""Speed of sound: the paper's camera-scaled fit (section IV-G). (The speed of sound of air
from its temperature and humidity, Cramer's formula, is `kernel.air.speed_of_sound`.)

Why fit c instead of measuring temperature: the microphone solver only sees ranges c * TOF
against source positions measured by the camera. An error in the camera's metric scale
(checkerboard print, focal length) is then almost exactly absorbed by c (positions x k and
c x k leave every TOF unchanged), so the "scaled" c fitted against camera distances gives
better microphone positions than the physically true c. The paper fits it from a reference
microphone on a stand whose position the camera also measures.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SpeedOfSoundFit:
    """Result of `fit_speed_of_sound`.

    Attributes:
        speed_of_sound_m_s: fitted c.
        speed_of_sound_std_m_s: its standard error.
        latency_s: the fitted common latency delta (TOF = d / c + delta); 0 without intercept.
        latency_std_s: its standard error (0 without intercept).
        residual_rms_m: RMS of the distance residuals d - c (t - delta), metres.
        n: number of (distance, TOF) pairs used.
    """

    speed_of_sound_m_s: float
    speed_of_sound_std_m_s: float
    latency_s: float
    latency_std_s: float
    residual_rms_m: float
    n: int


def fit_speed_of_sound(
    distances_m: np.ndarray,
    tofs_s: np.ndarray,
    intercept: bool = False,
    distance_std_m: float | np.ndarray | None = None,
    tof_std_s: float | np.ndarray | None = None,
    absolute_sigma: bool = False,
) -> SpeedOfSoundFit:
    """Least-squares c from camera distances (speaker -> reference microphone) and their TOFs.

    Model: d_i = c (t_i - delta) + e_i, fitted as the straight line d = c t + b (b = -c delta)
    by weighted least squares of d on t, because the camera's distance errors (~0.5 mm, i.e.
    ~1.5 us) dominate the TOF errors (~10 ns). Each point weighs 1 / (sigma_d^2 + c^2 sigma_t^2)
    with c from an unweighted first pass; with neither sigma given all weights are equal.

    Args:
        distances_m: (n,) distances from the camera-measured speaker positions to the
            camera-measured reference microphone.
        tofs_s: (n,) measured times of flight (NaN entries are skipped).
        intercept: also fit delta, a latency common to all TOFs (e.g. an uncorrected channel
            latency). Needs a spread of distances; without it c absorbs the latency.
        distance_std_m, tof_std_s: per-point or common standard deviations.
        absolute_sigma: take the sigmas as exact (standard errors from them alone); otherwise
            the standard errors are scaled by the residual scatter (chi^2 per dof), as the
            paper's standard deviation is.
    """
    d = np.asarray(distances_m, dtype=float).ravel()
    t = np.asarray(tofs_s, dtype=float).ravel()
    ok = np.isfinite(d) & np.isfinite(t)
    n_params = 2 if intercept else 1
    if ok.sum() <= n_params:
        raise ValueError(f"need more than {n_params} finite (distance, TOF) pairs")
    design = np.stack([t, np.ones_like(t)], axis=1)[:, :n_params]

    def solve(weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = design[ok] * np.sqrt(weights)[:, None]
        coef, *_ = np.linalg.lstsq(a, d[ok] * np.sqrt(weights), rcond=None)
        return coef, np.linalg.inv(a.T @ a)

    weights = np.ones(ok.sum())
    coef, cov = solve(weights)
    if distance_std_m is not None or tof_std_s is not None:
        sd = np.broadcast_to(0.0 if distance_std_m is None else distance_std_m, d.shape)[ok]
        st = np.broadcast_to(0.0 if tof_std_s is None else tof_std_s, d.shape)[ok]
        weights = 1.0 / (sd**2 + (coef[0] * st) ** 2)
        coef, cov = solve(weights)
    residual = d[ok] - design[ok] @ coef
    if not absolute_sigma:
        cov = cov * np.sum(weights * residual**2) / (ok.sum() - n_params)

    c = float(coef[0])
    if intercept:
        b = float(coef[1])
        grad = np.array([b / c**2, -1.0 / c])  # d(delta)/d(c, b), delta = -b / c
        latency, latency_std = -b / c, float(np.sqrt(grad @ cov @ grad))
    else:
        latency, latency_std = 0.0, 0.0
    return SpeedOfSoundFit(
        speed_of_sound_m_s=c,
        speed_of_sound_std_m_s=float(np.sqrt(cov[0, 0])),
        latency_s=latency,
        latency_std_s=latency_std,
        residual_rms_m=float(np.sqrt(np.mean(residual**2))),
        n=int(ok.sum()),
    )


def fit_speed_of_sound_robust(distances_m: np.ndarray, tofs_s: np.ndarray,
                              threshold: float = 4.0, max_rounds: int = 10) -> SpeedOfSoundFit:
    """`fit_speed_of_sound` with outliers left out: pairs whose distance residual exceeds
    `threshold` robust sigmas (1.4826 x median |residual|) are dropped and the line refitted
    until the kept set settles. Why: a reference microphone on its stand that a tilted rig
    turns its back on hears a reflection first now and then (milliseconds late), and one
    such pair moves c by metres per second."""
    d = np.asarray(distances_m, dtype=float).ravel()
    t = np.asarray(tofs_s, dtype=float).ravel()
    keep = np.isfinite(d) & np.isfinite(t)
    fit = fit_speed_of_sound(d[keep], t[keep])
    for _ in range(max_rounds):
        residual = np.abs(d - fit.speed_of_sound_m_s * t)
        sigma = 1.4826 * float(np.median(residual[keep]))
        new_keep = np.isfinite(d) & np.isfinite(t) & (residual <= threshold * max(sigma, 1e-9))
        if np.array_equal(new_keep, keep) or new_keep.sum() < 3:
            break
        keep = new_keep
        fit = fit_speed_of_sound(d[keep], t[keep])
    return fit
