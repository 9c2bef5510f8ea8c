"""CLEAN-SC's dirty map under its updates, exact wherever it is read, without sweeping the
whole grid at every component (see `LazyMap`; used by `cleansc`)."""

from __future__ import annotations

import numpy as np

BLOCK_POINTS = 256
"""Points per block of `LazyMap`."""

SHRINK_BELOW = 0.1
"""`LazyMap` stops updating an exact block at every component once its maximum is below this
fraction of the map's maximum."""

RESORT_EVERY = 16
"""`LazyMap` re-sorts its exact points by value every this many components, so that the exact
set follows the map as it changes shape."""


class LazyMap:
    """A dirty map under CLEAN-SC updates B <- B - c_j b_j, exact wherever it is read.

    The points are sorted by their dirty-map value, highest first, and cut into blocks of
    `BLOCK_POINTS`; the steering vectors are copied in that order, so that every block is
    contiguous. The first `active` blocks are exact: every component is applied to them as it
    comes (one matrix-vector product). Every other block keeps the values of its last update,
    its maximum then and its epoch (the number of components then). A component can raise a
    point by at most c_j sum_m max_x |h_m(x)|^2 |g_jm|^2 (b_j >= -sum_m |h_m|^2 |g_jm|^2 with
    the diagonal removed, b_j >= 0 with it kept); `raised[k]` sums that over the first k
    components, so a stale block's values are at most its maximum + raised[n] - raised[epoch].
    While the exact blocks' maximum is at least every such bound, it is the map's maximum.
    Otherwise the block with the highest bound is brought up to date (all its pending
    components in one matrix product) and, if its maximum is within `SHRINK_BELOW` of the peak,
    swapped in next to the exact blocks and kept exact. The exact points are re-sorted by value
    now and then (`RESORT_EVERY`) and their last blocks let go once their maximum is below
    `SHRINK_BELOW` of the peak. As the components are removed
    the map falls, so the exact set follows its top while the rest is touched only when the
    peak has fallen to its level, with all its pending components at once; Acoular re-beamforms
    the whole grid at every component instead.
    """

    def __init__(self, values: np.ndarray, h: np.ndarray, power: np.ndarray,
                 remove_diagonal: bool, max_components: int,
                 block_points: int = BLOCK_POINTS) -> None:
        self.order = np.argsort(-values, kind="stable")
        self.position = np.empty_like(self.order)  # inverse permutation
        self.position[self.order] = np.arange(self.order.size)
        self.values = values[self.order]
        self.h = h[self.order]
        self.power = power[self.order]
        self.remove_diagonal = remove_diagonal
        # max over the points of |h_m|^2, per microphone (0 with the diagonal kept)
        self.power_max = power.max(axis=0) if remove_diagonal else np.zeros(power.shape[1])
        self.size = max(int(block_points), 1)
        self.edges = np.append(np.arange(0, values.size, self.size), values.size)
        n_blocks = self.edges.size - 1
        self.epoch = np.zeros(n_blocks, dtype=np.intp)
        self.block_max = self.values[self.edges[:-1]].copy()  # sorted: each block's first
        self.active = 1
        self.sorted_at = 0  # the number of components at the last re-sort
        self.history_conj = np.empty((max_components, h.shape[1]), dtype=np.complex128)
        self.history_c = np.empty(max_components)
        self.raised = np.zeros(max_components + 1)
        self.n = 0

    def _beam(self, h: np.ndarray, power: np.ndarray, start: int) -> np.ndarray:
        """sum_j c_j b_j (r,) at rows h (r, M) with |h|^2 power (r, M), over the components
        j from `start` to now, b_j = |h^H g_j|^2 (minus sum_m |h_m|^2 |g_jm|^2 without the
        diagonal)."""
        g_conj = self.history_conj[start:self.n]  # (k, M)
        c = self.history_c[start:self.n]
        projection = h @ g_conj.T  # (r, k)
        beam = (projection.real**2 + projection.imag**2) @ c
        if self.remove_diagonal:
            beam -= power @ ((g_conj.real**2 + g_conj.imag**2).T @ c)
        return beam

    def _rows(self, block: int) -> slice:
        return slice(self.edges[block], self.edges[block + 1])

    def _update(self, block: int) -> None:
        """Bring a stale block up to date."""
        if self.epoch[block] < self.n:
            rows = self._rows(block)
            self.values[rows] -= self._beam(self.h[rows], self.power[rows],
                                            int(self.epoch[block]))
            self.epoch[block] = self.n
            self.block_max[block] = self.values[rows].max()

    def _swap(self, a: int, b: int) -> None:
        """Exchange the points of two blocks of the same size (with their state)."""
        ra, rb = self._rows(a), self._rows(b)
        for name in ("values", "h", "power", "order"):
            array = getattr(self, name)
            array[ra], array[rb] = array[rb].copy(), array[ra].copy()
        self.position[self.order[ra]] = np.arange(ra.start, ra.stop)
        self.position[self.order[rb]] = np.arange(rb.start, rb.stop)
        for state in (self.epoch, self.block_max):
            state[a], state[b] = state[b], state[a]

    def _activate(self, block: int) -> None:
        """Make an up-to-date stale block exact: move it next to the exact ones."""
        last = self.epoch.size - 1
        if block != self.active and block != last and self.active != last:
            self._swap(block, self.active)
        elif block == last and self.active != last:
            # the last block may be shorter: make every block between exact instead
            for b in range(self.active, last):
                self._update(b)
            self.active = last
        self.active += 1

    def _resort_exact(self) -> None:
        """Sort the exact points by their current values (highest first)."""
        end = self.edges[self.active]
        order = np.argsort(-self.values[:end], kind="stable")
        for name in ("values", "h", "power", "order"):
            array = getattr(self, name)
            array[:end] = array[:end][order]
        self.position[self.order[:end]] = np.arange(end)

    def _shrink(self, best: float) -> None:
        """Let go of the last exact blocks while their maximum is below SHRINK_BELOW * best."""
        while self.active > 1:
            last = self.active - 1
            top = float(self.values[self._rows(last)].max())
            if top >= SHRINK_BELOW * best:
                break
            self.block_max[last] = top  # exact now, stale from the next component on
            self.epoch[last] = self.n
            self.active = last

    def subtract(self, coefficient: float, g: np.ndarray) -> None:
        """B <- B - coefficient * b(g)."""
        n, end = self.n, self.edges[self.active]
        g_conj = self.history_conj[n]
        np.conjugate(g, out=g_conj)
        self.history_c[n] = coefficient
        projection = (self.h[:end] @ g_conj).view(np.float64).reshape(-1, 2)
        beam = np.einsum("gk,gk->g", projection, projection)
        g_power = g.real * g.real + g.imag * g.imag
        if self.remove_diagonal:
            beam -= self.power[:end] @ g_power
        beam *= coefficient
        self.values[:end] -= beam
        self.raised[n + 1] = self.raised[n] + coefficient * float(self.power_max @ g_power)
        self.n = n + 1

    def peak(self) -> tuple[int, float]:
        """Index (in the caller's order) and value of the map's maximum."""
        n_blocks = self.epoch.size
        best = float(np.max(self.values[:self.edges[self.active]]))
        while self.active < n_blocks:
            stale = slice(self.active, n_blocks)
            bounds = self.block_max[stale] + (self.raised[self.n] - self.raised[self.epoch[stale]])
            t = self.active + int(np.argmax(bounds))
            if best >= bounds[t - self.active]:
                break
            self._update(t)
            if self.block_max[t] >= SHRINK_BELOW * best:  # near the top: keep it exact
                self._activate(t)
                best = max(best, float(self.block_max[t]))
        if self.active > 1 and self.n % RESORT_EVERY == 0 and self.n != self.sorted_at:
            self.sorted_at = self.n
            self._resort_exact()
            self._shrink(best)
        i = int(np.argmax(self.values[:self.edges[self.active]]))
        return int(self.order[i]), float(self.values[i])

    def steering(self, index: int) -> np.ndarray:
        """h (M,) of a point (caller's index)."""
        return self.h[self.position[index]]

    def at(self, indices: np.ndarray) -> np.ndarray:
        """Exact values at some points (caller's indices), without changing the state."""
        rows = self.position[np.asarray(indices)]
        blocks = np.searchsorted(self.edges, rows, side="right") - 1
        values = self.values[rows]
        for b in np.unique(blocks[blocks >= self.active]):
            pick = blocks == b
            r = rows[pick]
            values[pick] -= self._beam(self.h[r], self.power[r], int(self.epoch[b]))
        return values

    def full(self) -> np.ndarray:
        """The whole map, exact, in the caller's order."""
        for b in range(self.active, self.epoch.size):
            self._update(b)
        result = np.empty_like(self.values)
        result[self.order] = self.values
        return result
