"""The paper's microphone solver (Legg & Bradley, section IV-I), kept as the baseline that
micam's own solver (calibration.solve.solver) is measured against."""

from __future__ import annotations

import numpy as np

from .robust import robust_sigma
from .solver import MicrophoneSolution, RigSources, SolverOptions


def solve_paper_method(
    sources: np.ndarray | RigSources,
    tof_s: np.ndarray,
    tof_std_s: float | np.ndarray,
    options: SolverOptions | None = None,
    initial_step_m: float = 0.1,
    min_step_m: float = 1e-6,
    n_reweight: int = 3,
    max_sweeps: int = 5000,
) -> MicrophoneSolution:
    """The paper's solver (section IV-I, after Dobler et al.), kept as the baseline.

    Microphones start at [0, 0, 0] (the camera; no prior geometry, as in the paper's section
    V) and c is fixed (options.speed_of_sound_m_s, from the IV-G fit); sources are not refined
    (as in the paper's Table II runs) and there is no latency. For each microphone, in turn
    (vectorised here, as the per-microphone costs are independent once c and the sources
    are fixed), each coordinate is stepped by +-step while that lowers
    sum_s phi_ms^-2 (|X_m - S_s| / c - tau_ms)^2, and the step is halved when no move helps,
    down to `min_step_m` (steps 3-4). Then the weights of the sources that contribute most
    to the cost are reduced, phi_s^2 *= max(1, C_s / median C) (step 6), and the search is
    repeated (step 7). No covariance comes out of it (NaN).
    """
    options = options or SolverOptions()
    tof = np.asarray(tof_s, dtype=float)
    positions = np.asarray(sources.positions() if isinstance(sources, RigSources) else sources)
    sigma = np.broadcast_to(np.asarray(tof_std_s, dtype=float), tof.shape)
    valid = np.isfinite(tof) & (sigma > 0)
    weight = np.where(valid, 1.0 / np.where(valid, sigma, 1.0) ** 2, 0.0)  # (n_src, n_mic)
    tau = np.where(valid, tof, 0.0)
    c = options.speed_of_sound_m_s

    def residuals(X: np.ndarray) -> np.ndarray:
        return np.linalg.norm(X[None] - positions[:, None], axis=-1) / c - tau

    def cost(X: np.ndarray) -> np.ndarray:
        return np.sum(weight * residuals(X) ** 2, axis=0)

    X = np.zeros((tof.shape[1], 3))
    evaluations = 0
    for round_ in range(n_reweight + 1):
        step = np.full(X.shape[0], initial_step_m)
        current = cost(X)
        for _ in range(max_sweeps):
            active = step >= min_step_m
            if not active.any():
                break
            improved = np.zeros(X.shape[0], dtype=bool)
            for axis in range(3):
                for sign in (1.0, -1.0):
                    trial = X.copy()
                    trial[:, axis] += sign * step
                    trial_cost = cost(trial)
                    better = active & (trial_cost < current)
                    X[better], current[better] = trial[better], trial_cost[better]
                    improved |= better
            evaluations += 6
            step = np.where(improved, step, 0.5 * step)
        if round_ < n_reweight:
            contribution = np.sum(weight * residuals(X) ** 2, axis=1)
            weight = weight / np.maximum(1.0, contribution / np.median(contribution))[:, None]

    res = np.where(valid, tof - np.linalg.norm(X[None] - positions[:, None], axis=-1) / c, np.nan)
    return MicrophoneSolution(
        positions_m=X,
        covariance_m2=np.full((X.shape[0], 3, 3), np.nan),
        speed_of_sound_m_s=c,
        speed_of_sound_std_m_s=0.0,
        latency_s=np.zeros(1),
        latency_std_s=np.zeros(1),
        pose_corrections=None,
        pose_correction_std=None,
        residuals_s=res,
        outliers=np.zeros(tof.shape, dtype=bool),
        sigma_scale=robust_sigma(res[valid] / sigma[valid], floor=1e-6),
        chi2_per_dof=float(np.nanmean((res / sigma) ** 2)),
        nfev=evaluations,
    )
