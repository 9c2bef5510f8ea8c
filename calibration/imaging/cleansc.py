"""CLEAN-SC deconvolution (Sijtsma 2007, "CLEAN based on spatial source coherence").

Per frequency, starting from the dirty delay-and-sum map B and the CSM D (degraded in turn):

1. take the peak x_j = argmax B and its value B_max; the component's power is loop_gain * B_max;
2. its coherent source vector g (M,) solves, with w = sqrt(M/(M-1)) h(x_j) and the diagonal of
   D removed (D0):  g = (D0 w / B_max + H w) / sqrt(1 + w^H H w),  H = diag(|g|^2),
   by fixed-point iteration from g = w (20 rounds, as in Acoular); with the diagonal kept,
   g = D w / B_max exactly. The source's CSM is G_j = B_max g g^H;
3. degrade: D <- D - loop_gain G_j, and B <- B - loop_gain B_j with B_j the delay-and-sum map
   of G_j.

Step 3 uses the linearity of beamforming: B_j(x) = B_max |h(x)^H g|^2, minus
B_max sum_m |h_m(x)|^2 |g_m|^2 and times M/(M-1) when the diagonal is removed. Acoular instead
re-beamforms G_j over the whole grid from new sines and cosines at every iteration. Here the
update is applied lazily (`_LazyMap`): exactly, at every iteration, on a candidate set of the
highest points (one small matrix-vector product); for the other points the pending
components are applied together, one matrix product over the whole grid, only when a bound
on their values could reach the candidates' maximum. The peak of every iteration is the
exact peak of the fully updated map, so the result is Acoular's, to rounding.

The clean map is the sum of the components only (the residual is not added back), as in
Acoular. Stopping rules (`StopRule`): Acoular's "peak-rise" (stop once the peak exceeds the one
`stop_window` iterations earlier; that last component is kept), Sijtsma's "csm-norm" (stop
before a component that would increase the Frobenius norm of the off-diagonal degraded CSM),
or "none"; always at most `max_iterations` (default 2M) and, optionally, when the peak falls
`min_peak_db` below the first one.

Precision (`precision`): "double" (the default) is complex128 throughout. "single" computes
the dirty map and the whole-grid updates (most of the time) in complex64 and keeps the
candidates' exact updates, the coherence vectors and the degraded CSM in complex128; it is
about 30 % faster but NOT recommended: the complex64 rounding of the dirty map (6e-7 of its
maximum) is not cancelled by the updates, so once the sources are removed CLEAN-SC goes on
picking components from that rounding floor. On the benchmark workload (noise-free simulated
sources, 144 iterations per bin, peaks down to 1e-14 of the first) its clean maps differ from
the float64 ones by up to 1.3e-3 of each bin's maximum, against 3e-7 between float64 and
Acoular (whose float32 phases perturb the dirty map and the updates consistently).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from .._blas import single_threaded_blas
from .beamform import beamform_csm, complex_dtype, diagonal_norm
from .csm import CrossSpectra
from .peaks import subgrid_peak
from .steering import SteeringModel


class StopRule(StrEnum):
    PEAK_RISE = "peak-rise"
    CSM_NORM = "csm-norm"
    NONE = "none"


@dataclass(frozen=True)
class CleanScOptions:
    """CLEAN-SC settings.

    Attributes:
        loop_gain: fraction of each peak removed per iteration, 0 < gain <= 1 (Acoular 0.6).
        max_iterations: cap on iterations; None = 2 M (Acoular's default).
        stop_rule: see `StopRule` and the module docstring.
        stop_window: the look-back of the peak-rise rule (Acoular's `stopn`, 3).
        min_peak_db: stop when the peak is this many dB below the first peak (None: off).
        coherence_iterations: fixed-point rounds for g with the diagonal removed.
        remove_diagonal: work without the CSM's diagonal (autospectra).
    """

    loop_gain: float = 0.6
    max_iterations: int | None = None
    stop_rule: StopRule = StopRule.PEAK_RISE
    stop_window: int = 3
    min_peak_db: float | None = None
    coherence_iterations: int = 20
    remove_diagonal: bool = True

    def __post_init__(self) -> None:
        if not 0.0 < self.loop_gain <= 1.0:
            raise ValueError(f"loop gain {self.loop_gain} must be in (0, 1]")
        if self.max_iterations is not None and self.max_iterations < 1:
            raise ValueError(f"max_iterations {self.max_iterations} must be >= 1")
        if self.stop_window < 1 or self.coherence_iterations < 1:
            raise ValueError("stop_window and coherence_iterations must be >= 1")
        if self.min_peak_db is not None and self.min_peak_db <= 0:
            raise ValueError(f"min_peak_db {self.min_peak_db} must be positive")
        object.__setattr__(self, "stop_rule", StopRule(self.stop_rule))


@dataclass(frozen=True)
class Component:
    """One CLEAN-SC source component.

    Attributes:
        index: flat index of its scan point.
        power: loop_gain * B_max, the power it adds to the clean map.
        peak: B_max, the dirty-map peak it was taken from.
        subgrid: fractional grid index (i, j) of the dirty-map peak (quadratic fit), when the
            scan points form a 2-D grid.
        coherence: g (M,), the source's coherent pressure vector (G_j = B_max g g^H).
    """

    index: int
    power: float
    peak: float
    subgrid: tuple[float, float] | None
    coherence: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class CleanScResult:
    """CLEAN-SC of one CSM: the clean map (G,), the residual dirty map (G,), the components."""

    clean_map: np.ndarray
    residual_map: np.ndarray
    components: list[Component]

    @property
    def n_iterations(self) -> int:
        return len(self.components)


def _offdiag_norm(d: np.ndarray) -> float:
    """Frobenius norm of the off-diagonal part of a matrix (M, M)."""
    diagonal = np.diagonal(d)
    total = np.sum((d * d.conj()).real) - np.sum((diagonal * diagonal.conj()).real)
    return float(np.sqrt(max(total, 0.0)))


def _coherence(d: np.ndarray, w: np.ndarray, peak: float, options: CleanScOptions
               ) -> np.ndarray:
    """The source vector g (M,) of the component at steering w (see the module docstring)."""
    if not options.remove_diagonal:
        return (d @ w) / peak
    d1 = (d @ w - np.diagonal(d) * w) / peak
    # The rounds g <- (d1 + |g|^2 w) / sqrt(1 + |w|^2 . |g|^2), from g = w, depend on g only
    # through p = |g|^2, so they are run on p (real): p <- (|d1|^2 + p (2 Re(d1* w) + p |w|^2))
    # / (1 + |w|^2 . p), and g is formed from the last p. The same g as the complex rounds,
    # to rounding (about 1e-16), with fewer and real operations.
    w_power = w.real * w.real + w.imag * w.imag
    d1_power = d1.real * d1.real + d1.imag * d1.imag
    cross = 2.0 * (d1.real * w.real + d1.imag * w.imag)
    p = w_power
    for _ in range(options.coherence_iterations - 1):
        scale = 1.0 / (1.0 + float(w_power @ p))
        q = p * w_power
        q += cross
        q *= p
        q += d1_power
        q *= scale
        p = q
    g = d1 + p * w
    g *= 1.0 / math.sqrt(1.0 + float(w_power @ p))
    return g


class _LazyMap:
    """A dirty map under CLEAN-SC updates B <- B - c_j b_j, exact wherever it is read.

    `values` is exact as of the last refresh; the components since then are pending. A
    candidate set S (the highest points at the refresh) is kept exact at every update. For a
    point outside S, b_j >= -sum_m |h_m|^2 |g_m|^2 >= -sum_m max_x |h_m(x)|^2 |g_m|^2 (and
    b_j >= 0 with the diagonal kept), so its value is at most tau + bound, with tau its
    maximum at the refresh and bound the sum of c_j sum_m max_x |h_m(x)|^2 |g_jm|^2. While the
    candidates' maximum is at least that, it is the map's maximum; otherwise the pending
    components are applied to all points (one (G x M) (M x k) product) and S is chosen again.
    """

    def __init__(self, values: np.ndarray, h: np.ndarray, power: np.ndarray,
                 remove_diagonal: bool, n_candidates: int, dtype: type = np.complex128
                 ) -> None:
        self.values = values
        self.h = h
        self.h_full = h.astype(dtype, copy=False)  # for the whole-grid products
        self.power = power
        self.remove_diagonal = remove_diagonal
        # max over the points of |h_m|^2, per microphone (0 with the diagonal kept)
        self.power_max = power.max(axis=0) if remove_diagonal else np.zeros(power.shape[1])
        self.n_candidates = min(max(n_candidates, 1), values.size)
        self.pending_g: list[np.ndarray] = []
        self.pending_c: list[float] = []
        self.refreshes = 0
        self._select()

    def _beam(self, h: np.ndarray, power: np.ndarray, g: np.ndarray) -> np.ndarray:
        """b (n,) = |h^H g|^2 (minus sum_m |h_m|^2 |g_m|^2 without the diagonal)."""
        projection = (h @ g.conj()).view(np.float64).reshape(-1, 2)
        beam = np.einsum("gk,gk->g", projection, projection)
        if self.remove_diagonal:
            beam -= power @ (g * g.conj()).real
        return beam

    def _select(self) -> None:
        k = self.n_candidates
        if k == self.values.size:
            self.candidates = np.arange(k)
            self.tau = -np.inf
        else:
            order = np.argpartition(self.values, self.values.size - k - 1)
            self.candidates = np.sort(order[self.values.size - k:])
            self.tau = float(self.values[order[self.values.size - k - 1]])
        self.h_c = self.h[self.candidates]
        self.power_c = self.power[self.candidates]
        self.values_c = self.values[self.candidates]
        self.bound = 0.0

    def _apply_pending(self) -> None:
        if not self.pending_g:
            return
        g = np.array(self.pending_g)  # (k, M)
        c = np.array(self.pending_c)
        projection = self.h_full @ g.conj().T.astype(self.h_full.dtype)  # (G, k)
        self.values -= (projection.real**2 + projection.imag**2) @ c
        if self.remove_diagonal:
            self.values += self.power @ ((g * g.conj()).real.T @ c)
        self.pending_g.clear()
        self.pending_c.clear()

    def subtract(self, coefficient: float, g: np.ndarray) -> None:
        """B <- B - coefficient * b(g)."""
        self.values_c -= coefficient * self._beam(self.h_c, self.power_c, g)
        self.pending_g.append(g)
        self.pending_c.append(coefficient)
        self.bound += coefficient * float(self.power_max @ (g.real * g.real + g.imag * g.imag))

    def peak(self) -> tuple[int, float]:
        """Index and value of the map's maximum."""
        i = int(np.argmax(self.values_c))
        if self.values_c[i] < self.tau + self.bound:
            self._apply_pending()
            self._select()
            self.refreshes += 1
            i = int(np.argmax(self.values_c))
        return int(self.candidates[i]), float(self.values_c[i])

    def at(self, indices: np.ndarray) -> np.ndarray:
        """Exact values at some points."""
        values = self.values[indices]
        for g, c in zip(self.pending_g, self.pending_c, strict=True):
            values -= c * self._beam(self.h[indices], self.power[indices], g)
        return values

    def full(self) -> np.ndarray:
        """The whole map, exact (the last call: the candidates are not kept up to date)."""
        self._apply_pending()
        return self.values


def _subgrid(lazy: _LazyMap, index: int, shape: tuple[int, int]) -> tuple[float, float]:
    """Sub-grid peak from the exact 3 x 3 neighbourhood of a node."""
    i, j = np.unravel_index(index, shape)
    rows = np.arange(max(i - 1, 0), min(i + 2, shape[0]))
    cols = np.arange(max(j - 1, 0), min(j + 2, shape[1]))
    flat = (rows[:, None] * shape[1] + cols[None, :]).ravel()
    local = lazy.at(flat).reshape(rows.size, cols.size)
    fi, fj = subgrid_peak(local, local.shape, int(np.flatnonzero(flat == index)[0]))
    return float(rows[0] + fi), float(cols[0] + fj)


def clean_sc(csm: np.ndarray, h: np.ndarray, options: CleanScOptions | None = None,
             h_power: np.ndarray | None = None, grid_shape: tuple[int, int] | None = None,
             candidate_fraction: float = 1 / 8, precision: str = "double") -> CleanScResult:
    """CLEAN-SC of one CSM (M, M) with steering vectors h (G, M).

    Args:
        h_power: |h|^2 (G, M) if known (frequency-independent); computed otherwise.
        grid_shape: (n_u, n_v) when the G points form a grid (u slowest): each component then
            records the sub-grid position of its dirty-map peak.
        candidate_fraction: share of the points kept exact at every iteration (`_LazyMap`);
            it changes the speed, not the result.
        precision: "single" or "double" (see the module docstring).
    """
    options = options or CleanScOptions()
    if not 0.0 < candidate_fraction <= 1.0:
        raise ValueError(f"candidate_fraction {candidate_fraction} must be in (0, 1]")
    csm = np.asarray(csm)
    m = csm.shape[-1]
    power = h_power if h_power is not None else h.real**2 + h.imag**2
    if power.shape != h.shape:
        raise ValueError(f"|h|^2 {power.shape} and steering vectors {h.shape} differ in shape")
    norm = diagonal_norm(m, options.remove_diagonal)
    gain = options.loop_gain
    dtype = complex_dtype(precision)
    dirty = beamform_csm(h, csm, options.remove_diagonal, power, precision=precision)
    degraded = np.array(csm, dtype=np.complex128, copy=True)
    clean = np.zeros(h.shape[0])
    components: list[Component] = []
    peaks: list[float] = []
    floor = -np.inf
    csm_norm = _offdiag_norm(degraded)
    with single_threaded_blas():
        lazy = _LazyMap(dirty, h, power, options.remove_diagonal,
                        int(np.ceil(candidate_fraction * h.shape[0])), dtype)
        for j in range(options.max_iterations or 2 * m):
            index, peak = lazy.peak()
            if j == 0 and options.min_peak_db is not None:
                floor = peak * 10 ** (-options.min_peak_db / 10)
            if peak <= 0 or peak < floor:
                break
            g = _coherence(degraded, np.sqrt(norm) * h[index], peak, options)
            source = peak * np.outer(g, g.conj())
            if options.stop_rule is StopRule.CSM_NORM:
                new_norm = _offdiag_norm(degraded - gain * source)
                if new_norm >= csm_norm:
                    break
                csm_norm = new_norm
            subgrid = _subgrid(lazy, index, grid_shape) if grid_shape is not None else None
            components.append(Component(index, gain * peak, peak, subgrid, g))
            clean[index] += gain * peak
            peaks.append(peak)
            if (options.stop_rule is StopRule.PEAK_RISE and j > options.stop_window
                    and peak > peaks[j - options.stop_window]):
                break
            lazy.subtract(gain * peak * norm, g)
            degraded -= gain * source
        residual = lazy.full()
    return CleanScResult(clean, residual, components)


def clean_sc_spectra(spectra: CrossSpectra, steering: SteeringModel,
                     options: CleanScOptions | None = None,
                     grid_shape: tuple[int, int] | None = None, precision: str = "double"
                     ) -> list[CleanScResult]:
    """CLEAN-SC at every frequency of `spectra`; sum the clean maps for a band map.
    `precision`: see the module docstring."""
    if spectra.n_channels != steering.n_mics:
        raise ValueError(f"the CSM has {spectra.n_channels} channels but the steering model "
                         f"{steering.n_mics} microphones")
    power = steering.amplitude**2
    work = np.empty_like(steering.path_difference, dtype=np.complex128)
    return [clean_sc(spectra.csm[i], h, options, power, grid_shape, precision=precision)
            for i, h in enumerate(steering.vectors_at(spectra.freqs_hz, out=work))]
