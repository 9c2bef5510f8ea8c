"""Peaks of maps on regular 2-D grids, to a fraction of the grid spacing.

A map's maximum is quantised to the grid: on average 0.38 of the spacing off in 2-D for a
uniformly placed source. Near its maximum a beamforming map is smooth (its main lobe is many
grid cells wide at the usual spacings), so a quadratic surface fitted to the 3 x 3 neighbourhood
of the peak node puts the maximum far closer to the truth.
"""

from __future__ import annotations

import numpy as np

# Least-squares fit of f = a + b x + c y + d x^2 + e y^2 + g x y on the 3 x 3 stencil.
_STENCIL = np.array([(x, y) for x in (-1, 0, 1) for y in (-1, 0, 1)], dtype=np.float64)
_DESIGN = np.column_stack([np.ones(9), _STENCIL[:, 0], _STENCIL[:, 1], _STENCIL[:, 0] ** 2,
                           _STENCIL[:, 1] ** 2, _STENCIL[:, 0] * _STENCIL[:, 1]])
_FIT = np.linalg.pinv(_DESIGN)  # (6, 9)


def quadratic_offset(patch: np.ndarray) -> tuple[float, float]:
    """Offset (di, dj) of the maximum of the quadratic fitted to a 3 x 3 patch centred on a
    local maximum, in grid cells, each within [-1, 1]. (0, 0) when the fit has no maximum."""
    patch = np.asarray(patch, dtype=np.float64)
    if patch.shape != (3, 3):
        raise ValueError(f"a quadratic peak fit needs a 3 x 3 patch, got {patch.shape}")
    _, b, c, d, e, g = (float(x) for x in _FIT @ patch.ravel())
    # Stationary point of the fit: [[2d, g], [g, 2e]] (di, dj) = (-b, -c); a maximum needs
    # a negative definite Hessian.
    det = 4 * d * e - g * g
    if not (d < 0 and det > 0):
        return 0.0, 0.0
    di = (-2 * e * b + g * c) / det
    dj = (-2 * d * c + g * b) / det
    return min(max(di, -1.0), 1.0), min(max(dj, -1.0), 1.0)


def subgrid_peak(values: np.ndarray, shape: tuple[int, int], flat_index: int | None = None
                 ) -> tuple[float, float]:
    """Fractional grid index (i, j) of a map's peak.

    Args:
        values: the map, flat (n_u * n_v,) or (n_u, n_v).
        shape: (n_u, n_v).
        flat_index: the peak node (default: the maximum). On the grid's border the offset
            across the border is 0.
    """
    grid = np.asarray(values, dtype=np.float64).reshape(shape)
    if flat_index is None:
        flat_index = int(np.argmax(grid))
    i, j = (int(k) for k in np.unravel_index(flat_index, shape))
    lo_i, lo_j = max(i - 1, 0), max(j - 1, 0)
    patch = np.full((3, 3), np.nan)
    patch[lo_i - i + 1: min(i + 2, shape[0]) - i + 1, lo_j - j + 1: min(j + 2, shape[1]) - j + 1
          ] = grid[lo_i: i + 2, lo_j: j + 2]
    inside = ~np.isnan(patch)
    if inside.all():
        di, dj = quadratic_offset(patch)
        return i + di, j + dj
    # On a border: a 1-D parabola along each axis that has both neighbours.
    offsets = []
    for line in (patch[:, 1], patch[1, :]):
        if np.isnan(line).any():
            offsets.append(0.0)
            continue
        curvature = line[0] - 2 * line[1] + line[2]
        offsets.append(float(np.clip(0.5 * (line[0] - line[2]) / curvature, -1, 1))
                       if curvature < 0 else 0.0)
    return i + offsets[0], j + offsets[1]
