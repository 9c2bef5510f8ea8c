"""Cramer-Rao bounds of microphone positions from times of flight (calibration-math.md (a)).

Two bounds:

- `mic_position_crlb`: each microphone alone, c and latency known, sources at the camera's
  estimate. With tau_s = |x - s_s| / c + n_s and u_s the unit vector from source to mic,

      Cov(x) >= J^-1,   J = sum_s u_s u_s^T / (c^2 sigma_t^2 + u_s^T Sigma_p u_s),

  where isotropic source noise of sigma_p per axis enters as equivalent timing noise
  (sigma_eq^2 = sigma_t^2 + sigma_p^2 / c^2). For one microphone this is exact; across
  microphones the source errors are shared (mostly a common translation).
- `joint_crlb`: all microphones together with c, latencies and the camera errors as unknowns:
  either one 3-vector per source with an isotropic prior (source_std_m) or one rigid 6-dof
  correction per rig pose with the camera's pose covariance as prior (errors-in-variables).
  The nuisance blocks are eliminated by a Schur complement, as in bundle adjustment. This is
  the bound to compare a joint solver with, and it shows what fitting c and a latency costs
  when the source errors are shared by all microphones.

`expected_error_norm` turns a 3x3 covariance into E|e| (the "mean error" of the benchmarks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from calibration.choices import DEFAULT_LATENCY, LatencyModel
from calibration.solve.solver import RigSources, SolverOptions, latency_columns
from kernel.rigid import rotated_point_jacobian


def mic_position_crlb(
    mics_m: np.ndarray,
    sources_m: np.ndarray,
    speed_of_sound_m_s: float,
    timing_std_s: float | np.ndarray,
    source_std_m: float | np.ndarray = 0.0,
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """(n_mic, 3, 3) per-microphone position bound, c and latency known (see module doc).

    Args:
        mics_m: (n_mic, 3) true microphone positions.
        sources_m: (n_src, 3) source positions.
        timing_std_s: scalar or (n_src, n_mic) TOF standard deviation.
        source_std_m: scalar or (n_src,) isotropic per-axis source-position standard deviation.
        valid: (n_src, n_mic) measurements that exist (default all).
    """
    diff = np.asarray(mics_m)[None] - np.asarray(sources_m)[:, None]  # (n_src, n_mic, 3)
    u = diff / np.linalg.norm(diff, axis=-1, keepdims=True)
    c = speed_of_sound_m_s
    source_var = np.broadcast_to(np.asarray(source_std_m, dtype=float) ** 2, (diff.shape[0],))
    var_m2 = c**2 * np.broadcast_to(timing_std_s, diff.shape[:2]) ** 2 + source_var[:, None]
    weight = 1.0 / var_m2
    if valid is not None:
        weight = np.where(valid, weight, 0.0)
    fisher = np.einsum("sm,smi,smj->mij", weight, u, u)
    return np.linalg.inv(fisher)


@dataclass(frozen=True)
class JointBound:
    """Result of `joint_crlb`.

    Attributes:
        mic_covariance_m2: (n_mic, 3, 3) bound on each microphone's position covariance.
        speed_of_sound_std_m_s: bound on the std of c (0 if c is known).
        latency_std_s: (n_latency,) bounds on the free latencies.
    """

    mic_covariance_m2: np.ndarray
    speed_of_sound_std_m_s: float
    latency_std_s: np.ndarray


def joint_crlb(
    mics_m: np.ndarray,
    sources: np.ndarray | RigSources,
    speed_of_sound_m_s: float,
    timing_std_s: float | np.ndarray,
    valid: np.ndarray | None = None,
    fit_speed_of_sound: bool = True,
    latency: LatencyModel = DEFAULT_LATENCY,
    board_of_mic: np.ndarray | None = None,
    reference_board: int | None = 0,
    source_std_m: float = 0.0,
    pose_errors: bool = False,
) -> JointBound:
    """Bound for microphones, c and latencies estimated jointly (errors-in-variables).

    Args:
        mics_m: (n_mic, 3) true positions; sources: (n_src, 3) or RigSources (true poses).
        timing_std_s: scalar or (n_src, n_mic).
        valid: (n_src, n_mic) measurements that exist (default all).
        fit_speed_of_sound, latency, board_of_mic, reference_board: the unknowns, as in
            `calibration.solve.solver.SolverOptions`.
        source_std_m: if > 0, every source position is a nuisance 3-vector with this
            isotropic prior (per axis).
        pose_errors: if True (sources must be RigSources with pose_covariance), every rig
            pose carries a nuisance rigid correction (rotvec, translation) with that prior.
    """
    mics = np.asarray(mics_m, dtype=float)
    positions = sources.positions() if isinstance(sources, RigSources) else np.asarray(sources)
    n_src, n_mic = positions.shape[0], mics.shape[0]
    valid = np.ones((n_src, n_mic), bool) if valid is None else np.asarray(valid, bool)
    src, mic = np.nonzero(valid)
    sigma = np.broadcast_to(np.asarray(timing_std_s, dtype=float), valid.shape)[valid]
    c = speed_of_sound_m_s

    diff = mics[mic] - positions[src]
    dist = np.linalg.norm(diff, axis=1)
    grad = diff / (dist * c * sigma)[:, None]  # whitened d tau / d X_m
    board = np.zeros(n_mic, int) if board_of_mic is None else np.asarray(board_of_mic)
    options = SolverOptions(latency=latency, reference_board=reference_board)
    board_col, n_lat = latency_columns(int(board.max()) + 1, options)
    lat_col = board_col[board[mic]]

    rows = np.arange(src.size)
    n_c = 1 if fit_speed_of_sound else 0
    n_global = 3 * n_mic + n_c + n_lat
    entries = [
        (np.repeat(rows, 3), (3 * mic[:, None] + np.arange(3)).ravel(), grad.ravel()),
        (rows, np.full(rows.size, 3 * n_mic), -dist / (c**2 * sigma)) if n_c else None,
        (rows[lat_col >= 0], 3 * n_mic + n_c + lat_col[lat_col >= 0], 1.0 / sigma[lat_col >= 0]),
    ]
    jac = _sparse(entries, (rows.size, n_global))
    fisher = (jac.T @ jac).toarray()

    nuisance = _nuisance(sources, positions, src, grad, source_std_m, pose_errors)
    if nuisance is not None:
        group, block, prior = nuisance  # (n_rows,), (n_rows, k), (n_group, k, k)
        k = block.shape[1]
        n_cols = (k * group[:, None] + np.arange(k)).ravel()
        jn = _sparse([(np.repeat(rows, k), n_cols, block.ravel())], (rows.size, k * prior.shape[0]))
        cross = (jac.T @ jn).toarray()  # (n_global, k n_group)
        fnn = (jn.T @ jn).toarray().reshape(prior.shape[0], k, prior.shape[0], k)
        fnn = fnn[np.arange(prior.shape[0]), :, np.arange(prior.shape[0]), :] + prior
        inv_blocks = np.linalg.inv(fnn)
        cross_g = cross.reshape(n_global, prior.shape[0], k)
        fisher -= np.einsum("agk,gkl,bgl->ab", cross_g, inv_blocks, cross_g)

    cov = np.linalg.inv(fisher)
    mic_cov = np.array([cov[3 * m : 3 * m + 3, 3 * m : 3 * m + 3] for m in range(n_mic)])
    std = np.sqrt(np.diag(cov))
    return JointBound(
        mic_covariance_m2=mic_cov,
        speed_of_sound_std_m_s=float(std[3 * n_mic]) if n_c else 0.0,
        latency_std_s=std[3 * n_mic + n_c :],
    )


def _sparse(entries: list, shape: tuple[int, int]) -> sparse.csr_matrix:
    entries = [e for e in entries if e is not None]
    rows, cols, vals = (np.concatenate(part) for part in zip(*entries, strict=False))
    return sparse.csr_matrix((vals, (rows, cols)), shape=shape)


def _nuisance(
    sources: np.ndarray | RigSources,
    positions: np.ndarray,
    src: np.ndarray,
    grad: np.ndarray,
    source_std_m: float,
    pose_errors: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Per-row group index, whitened Jacobian block and prior information of the nuisances."""
    if pose_errors:
        if not isinstance(sources, RigSources) or sources.pose_covariance is None:
            raise ValueError("pose_errors needs RigSources with pose_covariance")
        pose = sources.pose_of_source
        d_rot = rotated_point_jacobian(
            sources.rotvec[pose], sources.rig_points_m[sources.speaker_of_source]
        )
        d_src = np.concatenate([d_rot, np.broadcast_to(np.eye(3), d_rot.shape)], axis=2)
        block = -np.einsum("ri,riw->rw", grad, d_src[src])
        return pose[src], block, np.linalg.inv(sources.pose_covariance)
    if source_std_m > 0:
        prior = np.broadcast_to(np.eye(3) / source_std_m**2, (positions.shape[0], 3, 3))
        return src, -grad, prior
    return None


def expected_error_norm(covariance: np.ndarray) -> np.ndarray:
    """E|e| for zero-mean Gaussian errors with (..., 3, 3) covariance, exactly.

    With eigenvalues l_i, |e|^2 = sum l_i z_i^2 and E exp(-s|e|^2) = prod (1 + 2 s l_i)^-1/2;
    from sqrt(q) = (4 pi)^-1/2 int_0^inf (1 - exp(-s q)) s^-3/2 ds,

        E|e| = (4 pi)^-1/2 int (1 - prod_i (1 + 2 s l_i)^-1/2) s^-3/2 ds,

    evaluated with s = exp(v) / mean(l) by the trapezoid rule in v, which converges
    geometrically for this smooth, doubly exponentially decaying integrand. Isotropic check:
    sigma sqrt(8 / pi).
    """
    lam = np.maximum(np.linalg.eigvalsh(covariance), 0.0)  # (..., 3)
    scale = np.maximum(lam.mean(axis=-1, keepdims=True), np.finfo(float).tiny)
    v = np.linspace(-40.0, 40.0, 1601)
    s = np.exp(v) / scale  # (..., n_v)
    prod = np.prod((1.0 + 2.0 * s[..., None] * lam[..., None, :]) ** -0.5, axis=-1)
    integrand = (
        (1.0 - prod) * np.exp(-0.5 * v) * np.sqrt(scale)
    )  # ds s^-3/2 = e^{-v/2} sqrt(scale) dv
    return np.trapezoid(integrand, v, axis=-1) / np.sqrt(4.0 * np.pi)
