"""The closed-form start of the microphone solver: multilateration from ranges to known sources,
with a consensus over source subsets against outliers (reflections, a source in a null).
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import combinations

import numpy as np

from .robust import MAD_TO_SIGMA


def multilaterate(
    sources_m: np.ndarray,
    ranges_m: np.ndarray,
    valid: np.ndarray | None = None,
    camera_center_m: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    planar_tolerance_m: float = 0.01,
    inlier_threshold_m: float = 0.02,
    n_subsets: int = 32,
) -> np.ndarray:
    """Closed-form position of every microphone from its ranges to known sources.

    Squared ranges are linear in (x, |x|^2): |x - s|^2 = |x|^2 - 2 s.x + |s|^2 (the
    spherical-interpolation family). Solved per microphone, vectorised, in coordinates
    centred on that microphone's sources:

    - Non-coplanar sources: linear least squares for (x, q = |x|^2), 4 unknowns.
    - Coplanar sources (one rig pose, or RMS distance from their best plane below
      `planar_tolerance_m`): writing x = s_bar + E a + n z with E an in-plane basis and n the
      normal, |x - s|^2 = |a - y_s|^2 + z^2 is linear in (a, q = |a|^2 + z^2), and
      z = +-sqrt(q - |a|^2): the two roots are mirror images through the source plane.
      **Camera-side rule:** the sign of z is that of n.(camera_center - s_bar), i.e. the
      microphone is put on the same side of the source plane as the camera centre. This is
      right whenever the rig plane does not cut through the array (rig farther from the
      camera than the array extends behind/around it); the wrong root would put the array
      behind the board.

    Gross outliers (reflections picked instead of the direct path: 0.1-1 m of range) wreck a
    squared-range fit, so the fit starts from a consensus set: the fits to all sources and to
    `n_subsets` random 5-source subsets (fixed seed; all subsets when few sources) are scored
    per microphone by how many ranges they explain within `inlier_threshold_m`, and the best
    one's inliers are refitted. Remaining outliers are then rejected one at a time (the
    largest residual, when it exceeds 5 robust sigmas of the others, floor 0.5 mm).

    Args:
        sources_m: (n_src, 3) source positions.
        ranges_m: (n_src, n_mic) ranges c * TOF (NaN where missing).
        valid: (n_src, n_mic) usable measurements; defaults to the finite ranges.

    Returns:
        (n_mic, 3) positions; NaN for microphones with too few measurements (3 coplanar or 4
        non-coplanar sources are needed).
    """
    sources = np.asarray(sources_m, dtype=float)
    ranges = np.asarray(ranges_m, dtype=float)
    valid = np.isfinite(ranges) if valid is None else valid & np.isfinite(ranges)
    ranges = np.where(valid, ranges, 0.0)
    camera = np.asarray(camera_center_m, dtype=float)
    fit = lambda w: _multilaterate_weighted(sources, ranges, w, camera, planar_tolerance_m)  # noqa: E731
    keep = _consensus(fit, sources, ranges, valid, inlier_threshold_m, n_subsets)
    positions = np.full((ranges.shape[1], 3), np.nan)
    for _ in range(max(1, int(0.3 * sources.shape[0]) + 1)):
        positions = fit(keep)
        residual = _range_residuals(positions, sources, ranges)
        residual = np.where(keep > 0, np.nan_to_num(residual, nan=0.0), 0.0)
        worst = np.argmax(residual, axis=1)
        worst_value = residual[np.arange(residual.shape[0]), worst]
        others = np.where(keep > 0, residual, np.nan)
        others[np.arange(others.shape[0]), worst] = np.nan
        # a microphone with one kept range has no others: its scale is 0 (masked, no warning)
        scale = MAD_TO_SIGMA * np.ma.median(np.ma.masked_invalid(others), axis=1).filled(0.0)
        drop = (worst_value > 5.0 * np.maximum(scale, 5e-4)) & (keep.sum(1) > 5)
        if not drop.any():
            break
        keep[np.flatnonzero(drop), worst[drop]] = 0.0
    return positions


def _range_residuals(positions: np.ndarray, sources: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """(n_mic, n_src) |range mismatch| of positions (NaN positions give NaN)."""
    return np.abs(np.linalg.norm(positions[:, None] - sources, axis=-1) - ranges.T)


def _consensus(
    fit,
    sources: np.ndarray,
    ranges: np.ndarray,
    valid: np.ndarray,
    threshold: float,
    n_subsets: int,
) -> np.ndarray:
    """(n_mic, n_src) 0/1 inlier weights of the best-supported candidate fit per microphone."""
    n_src = sources.shape[0]
    rng = np.random.default_rng(0)
    subsets: list[np.ndarray]
    if n_src <= 8:
        subsets = [
            np.array(c) for k in (n_src - 1, n_src - 2) if k >= 3
            for c in combinations(range(n_src), k)
        ]
    else:
        subsets = [rng.choice(n_src, 5, replace=False) for _ in range(n_subsets)]
    best_count = np.full(valid.shape[1], -1)
    best = valid.T.astype(float)
    for subset in [np.arange(n_src), *subsets]:
        mask = np.zeros(n_src, dtype=bool)
        mask[subset] = True
        inlier = valid.T & (
            np.nan_to_num(_range_residuals(fit(valid.T * mask), sources, ranges), nan=np.inf)
            < threshold
        )
        count = inlier.sum(axis=1)
        better = count > best_count
        best[better], best_count[better] = inlier[better], count[better]
    enough = best_count >= 4
    return np.where(enough[:, None], best, valid.T.astype(float))


def _multilaterate_weighted(
    sources: np.ndarray, ranges: np.ndarray, weights: np.ndarray, camera: np.ndarray, tol: float
) -> np.ndarray:
    """One weighted pass of `multilaterate`; weights (n_mic, n_src) are 0/1 masks."""
    count = weights.sum(axis=1)
    centre = (weights @ sources) / np.maximum(count, 1.0)[:, None]  # (n_mic, 3)
    local = sources[None] - centre[:, None]  # (n_mic, n_src, 3)
    scatter = np.einsum("ms,msi,msj->mij", weights, local, local)
    eigval, eigvec = np.linalg.eigh(scatter)  # ascending
    thickness = np.sqrt(np.maximum(eigval[:, 0], 0.0) / np.maximum(count, 1.0))
    planar = thickness < tol

    rhs = ranges.T**2  # (n_mic, n_src)
    # Non-coplanar: rows [-2 s^T, 1] (x, q) = r^2 - |s|^2.
    design3 = np.concatenate([-2.0 * local, np.ones((*local.shape[:2], 1))], axis=-1)
    x3 = _weighted_lstsq(design3, rhs - np.sum(local**2, axis=-1), weights)[:, :3]
    # Coplanar: in-plane coordinates y = E^T s, then z from q - |a|^2 on the camera side.
    basis, normal = eigvec[:, :, 1:], eigvec[:, :, 0]
    y = np.einsum("msi,mik->msk", local, basis)
    design2 = np.concatenate([-2.0 * y, np.ones((*y.shape[:2], 1))], axis=-1)
    sol2 = _weighted_lstsq(design2, rhs - np.sum(y**2, axis=-1), weights)
    a, q = sol2[:, :2], sol2[:, 2]
    side = np.sign(np.einsum("mi,mi->m", normal, camera - centre))
    z = np.where(side == 0, 1.0, side) * np.sqrt(np.maximum(q - np.sum(a**2, axis=1), 0.0))
    x2 = np.einsum("mik,mk->mi", basis, a) + normal * z[:, None]

    positions = centre + np.where(planar[:, None], x2, x3)
    enough = np.where(planar, count >= 3, count >= 4)
    return np.where(enough[:, None], positions, np.nan)


def _weighted_lstsq(design: np.ndarray, rhs: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Batched weighted least squares via normal equations; NaN where singular."""
    normal = np.einsum("ms,msi,msj->mij", weights, design, design)
    moment = np.einsum("ms,msi,ms->mi", weights, design, rhs)
    out = np.full(moment.shape, np.nan)
    ok = np.linalg.cond(normal) < 1e12
    out[ok] = np.linalg.solve(normal[ok], moment[ok][..., None])[..., 0]
    return out
