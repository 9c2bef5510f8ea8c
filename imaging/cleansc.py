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
updates are applied lazily (`lazymap.LazyMap`): exactly, at every iteration, on a candidate
set of the highest points (one small matrix-vector product); every other point keeps the value
of its last update and an upper bound on what the components since then can have added, and
is only brought up to date (all its pending components in one matrix product) when that bound
could reach the candidates' maximum. The peak of every iteration is the exact peak of the fully
updated map, so the result is Acoular's, to rounding.

The clean map is the sum of the components only (the residual is not added back), as in
Acoular. Stopping rules (`StopRule`): Acoular's "peak-rise" (stop once the peak exceeds the one
`stop_window` iterations earlier; that last component is kept), Sijtsma's "csm-norm" (stop
before a component that would increase the Frobenius norm of the off-diagonal degraded CSM),
or "none"; always at most `max_iterations` (default 2M) and, optionally, when the peak falls
`min_peak_db` below the first one.

Precision: complex128 throughout, the dirty map included. Single precision was measured and
rejected: the complex64 rounding of the dirty map (6e-7 of its maximum) is not cancelled by
the updates, so once the sources are removed CLEAN-SC goes on picking components from that
rounding floor. On the benchmark workload (noise-free simulated sources, 144 iterations per
bin, peaks down to 1e-14 of the first) its clean maps differed from the float64 ones by up to
1.3e-3 of each bin's maximum, against 3e-7 between float64 and Acoular (whose float32 phases
perturb the dirty map and the updates consistently).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from calibration._blas import single_threaded_blas
from calibration._cores import resolve_workers
from calibration.errors import CalibrationInputError

from .beamform import beamform_csm, diagonal_norm
from .csm import CrossSpectra
from .lazymap import BLOCK_POINTS, LazyMap
from .parallel import run_in_processes
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
            raise CalibrationInputError(f"loop gain {self.loop_gain} must be in (0, 1]")
        if self.max_iterations is not None and self.max_iterations < 1:
            raise CalibrationInputError(f"max_iterations {self.max_iterations} must be >= 1")
        if self.stop_window < 1 or self.coherence_iterations < 1:
            raise CalibrationInputError("stop_window and coherence_iterations must be >= 1")
        if self.min_peak_db is not None and self.min_peak_db <= 0:
            raise CalibrationInputError(f"min_peak_db {self.min_peak_db} must be positive")
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
    """CLEAN-SC of one CSM: the clean map (G,), the components, and the residual dirty map
    (G,) when it was asked for (`clean_sc(..., residual=True)`; None otherwise)."""

    clean_map: np.ndarray
    components: list[Component]
    residual_map: np.ndarray | None = None

    @property
    def n_iterations(self) -> int:
        return len(self.components)


def _offdiag_norm(d: np.ndarray) -> float:
    """Frobenius norm of the off-diagonal part of a matrix (M, M)."""
    diagonal = np.diagonal(d)
    total = np.sum((d * d.conj()).real) - np.sum((diagonal * diagonal.conj()).real)
    return float(np.sqrt(max(total, 0.0)))


def _coherence(d: np.ndarray, w: np.ndarray, peak: np.ndarray, options: CleanScOptions
               ) -> np.ndarray:
    """The source vectors g (B, M) of components at steerings w (B, M), peaks (B,), with the
    degraded CSMs d (B, M, M): several CSMs at once (see the module docstring)."""
    dw = np.matmul(d, w[:, :, None])[:, :, 0]
    if not options.remove_diagonal:
        return dw / peak[:, None]
    d1 = (dw - np.diagonal(d, axis1=1, axis2=2) * w) / peak[:, None]
    # The rounds g <- (d1 + |g|^2 w) / sqrt(1 + |w|^2 . |g|^2), from g = w, depend on g only
    # through p = |g|^2, so they are run on p (real): p <- (|d1|^2 + p (2 Re(d1* w) + p |w|^2))
    # / (1 + |w|^2 . p), and g is formed from the last p. The same g as the complex rounds,
    # to rounding (about 1e-16), with fewer and real operations.
    w_power = w.real * w.real + w.imag * w.imag
    d1_power = d1.real * d1.real + d1.imag * d1.imag
    cross = 2.0 * (d1.real * w.real + d1.imag * w.imag)
    p = w_power
    for _ in range(options.coherence_iterations - 1):
        scale = 1.0 / (1.0 + np.einsum("bm,bm->b", w_power, p))
        q = p * w_power
        q += cross
        q *= p
        q += d1_power
        q *= scale[:, None]
        p = q
    g = d1 + p * w
    g *= (1.0 / np.sqrt(1.0 + np.einsum("bm,bm->b", w_power, p)))[:, None]
    return g


def _subgrid(lazy: LazyMap, index: int, shape: tuple[int, int]) -> tuple[float, float]:
    """Sub-grid peak from the exact 3 x 3 neighbourhood of a node."""
    i, j = (int(k) for k in np.unravel_index(index, shape))
    rows = np.arange(max(i - 1, 0), min(i + 2, shape[0]))
    cols = np.arange(max(j - 1, 0), min(j + 2, shape[1]))
    flat = (rows[:, None] * shape[1] + cols[None, :]).ravel()
    local = lazy.at(flat).reshape(rows.size, cols.size)
    fi, fj = subgrid_peak(local, local.shape, int(np.flatnonzero(flat == index)[0]))
    return float(rows[0] + fi), float(cols[0] + fj)


class _Deconvolution:
    """The CLEAN-SC of one CSM, one iteration at a time (`clean_sc_many` drives several).

    The degraded CSM is a view into the driver's stack, so that the coherence vectors and the
    CSM updates of all the CSMs are computed together.
    """

    def __init__(self, degraded: np.ndarray, h: np.ndarray, power: np.ndarray,
                 options: CleanScOptions, grid_shape: tuple[int, int] | None, block_points: int,
                 max_iterations: int, workers: int | None) -> None:
        self.options = options
        self.grid_shape = grid_shape
        self.degraded = degraded
        self.norm = diagonal_norm(degraded.shape[0], options.remove_diagonal)
        dirty = beamform_csm(h, degraded, options.remove_diagonal, power, "double", workers)
        self.lazy = LazyMap(dirty, h, power, options.remove_diagonal, max_iterations,
                                        block_points)
        self.clean = np.zeros(h.shape[0])
        self.components: list[Component] = []
        self.peaks: list[float] = []
        self.floor = -np.inf
        self.csm_norm = _offdiag_norm(degraded)
        self.done = False
        self.index, self.peak = -1, 0.0

    def find_peak(self) -> None:
        """The next component's point and peak; done when there is none."""
        self.index, self.peak = self.lazy.peak()
        if not self.peaks and self.options.min_peak_db is not None:
            self.floor = self.peak * 10 ** (-self.options.min_peak_db / 10)
        if self.peak <= 0 or self.peak < self.floor:
            self.done = True

    def steering(self) -> np.ndarray:
        """w = sqrt(M/(M-1)) h (M,) at the peak (the norm is 1 with the diagonal kept)."""
        return math.sqrt(self.norm) * self.lazy.steering(self.index)

    def accept(self, g: np.ndarray) -> bool:
        """Record the component of coherence vector g (unless a stop rule says otherwise) and
        update the map; True when the CSM is to be degraded by it and the iterations go on."""
        options, gain = self.options, self.options.loop_gain
        if options.stop_rule is StopRule.CSM_NORM:
            new_norm = _offdiag_norm(self.degraded - gain * self.peak * np.outer(g, g.conj()))
            if new_norm >= self.csm_norm:
                self.done = True
                return False
            self.csm_norm = new_norm
        subgrid = (_subgrid(self.lazy, self.index, self.grid_shape)
                   if self.grid_shape is not None else None)
        self.components.append(Component(self.index, gain * self.peak, self.peak, subgrid, g))
        self.clean[self.index] += gain * self.peak
        self.peaks.append(self.peak)
        j = len(self.peaks) - 1
        if (options.stop_rule is StopRule.PEAK_RISE and j > options.stop_window
                and self.peak > self.peaks[j - options.stop_window]):
            self.done = True
            return False
        self.lazy.subtract(gain * self.peak * self.norm, g)
        return True


def clean_sc_many(csms: np.ndarray, steerings: Iterable[np.ndarray], power: np.ndarray,
                  options: CleanScOptions | None = None,
                  grid_shape: tuple[int, int] | None = None,
                  block_points: int = BLOCK_POINTS, residual: bool = False,
                  workers: int | None = 1) -> list[CleanScResult]:
    """CLEAN-SC of several CSMs (B, M, M) on the same points, each with its steering vectors
    (G, M) (taken from `steerings` in turn, and copied; |h|^2 = `power` (G, M) for all, as
    for any frequency-independent amplitude), iterated together: the per-iteration work of
    all of them (coherence vectors, CSM updates) is done in one set of array operations
    instead of one per CSM, which divides the interpreter's share of the time by B. Each
    CSM's result is the one it would have alone. Arguments as for `clean_sc`.
    """
    options = options or CleanScOptions()
    degraded = np.array(csms, dtype=np.complex128, copy=True)
    m = degraded.shape[-1]
    max_iterations = options.max_iterations or 2 * m
    gain = options.loop_gain
    with single_threaded_blas():
        runs = [_Deconvolution(degraded[b], h, power, options, grid_shape, block_points,
                               max_iterations, workers)
                for b, h in zip(range(len(degraded)), steerings, strict=False)]
        if len(runs) != len(degraded):
            raise ValueError(f"{len(degraded)} CSMs but steering vectors for {len(runs)}")
        for _ in range(max_iterations):
            for run in runs:
                if not run.done:
                    run.find_peak()
            live = np.array([b for b, run in enumerate(runs) if not run.done], dtype=np.intp)
            if live.size == 0:
                break
            every = live.size == len(runs)
            d = degraded if every else degraded[live]
            peaks = np.array([runs[b].peak for b in live])
            g = _coherence(d, np.array([runs[b].steering() for b in live]), peaks, options)
            go_on = np.array([runs[b].accept(g[i]) for i, b in enumerate(live)])
            if not go_on.any():
                continue
            coefficient = gain * peaks * go_on
            sources = g[:, :, None] * g.conj()[:, None, :]
            sources *= coefficient[:, None, None]
            if every:
                degraded -= sources
            else:
                degraded[live] -= sources
        return [CleanScResult(run.clean, run.components, run.lazy.full() if residual else None)
                for run in runs]


def clean_sc(csm: np.ndarray, h: np.ndarray, options: CleanScOptions | None = None,
             h_power: np.ndarray | None = None, grid_shape: tuple[int, int] | None = None,
             block_points: int = BLOCK_POINTS, residual: bool = False,
             workers: int | None = None) -> CleanScResult:
    """CLEAN-SC of one CSM (M, M) with steering vectors h (G, M).

    Args:
        h_power: |h|^2 (G, M) if known (frequency-independent); computed otherwise.
        grid_shape: (n_u, n_v) when the G points form a grid (u slowest): each component then
            records the sub-grid position of its dirty-map peak.
        block_points: points per block of the lazy map (`LazyMap`); it changes the speed,
            not the result.
        residual: also return the residual dirty map (every component applied to every point:
            as much work again as the iterations themselves, so off by default; Acoular does
            not return it).
        workers: threads for the dirty map (None: all cores).
    """
    options = options or CleanScOptions()
    if block_points < 1:
        raise ValueError(f"block_points {block_points} must be at least 1")
    csm = np.asarray(csm)
    power = h_power if h_power is not None else h.real**2 + h.imag**2
    if power.shape != h.shape or csm.shape != (h.shape[1], h.shape[1]):
        raise ValueError(f"steering vectors {h.shape}, |h|^2 {power.shape} and CSM {csm.shape} "
                         "do not match: expected (G, M), (G, M) and (M, M)")
    return clean_sc_many(csm[None], [h], power, options, grid_shape, block_points,
                              residual, workers)[0]


LOCKSTEP_BINS = 4
"""Bins iterated together: enough to share out the interpreter's work, few enough that their
exact blocks stay in cache between iterations."""


def _clean_sc_bins(csms: np.ndarray, freqs_hz: np.ndarray, steering: SteeringModel,
                   options: CleanScOptions, grid_shape: tuple[int, int] | None,
                   lockstep: int) -> list[CleanScResult]:
    """CLEAN-SC of consecutive bins (CSMs (B, M, M) at freqs_hz (B,)), `lockstep` at a time,
    the steering vectors advanced from bin to bin: one job of `clean_sc_spectra`."""
    power = steering.amplitude**2
    vectors = steering.vectors_at(freqs_hz, shared=True)
    results: list[CleanScResult] = []
    for start in range(0, freqs_hz.size, lockstep):
        results.extend(clean_sc_many(csms[start:start + lockstep], vectors, power, options,
                                          grid_shape))
    return results


def clean_sc_spectra(spectra: CrossSpectra, steering: SteeringModel,
                     options: CleanScOptions | None = None,
                     grid_shape: tuple[int, int] | None = None, workers: int | None = 1,
                     lockstep: int = LOCKSTEP_BINS) -> list[CleanScResult]:
    """CLEAN-SC at every frequency of `spectra`; sum the clean maps for a band map.

    With `workers` > 1 (None: all cores) the bins are shared out, in contiguous runs (each
    advancing its own steering vectors from bin to bin), over that many worker processes
    (`parallel.process_pool`). Like every use of multiprocessing, that needs a script calling
    it to keep its top-level work under `if __name__ == "__main__":`, since each worker
    process imports the main module. Within a run, groups of `lockstep` bins are iterated
    together (`clean_sc_many`). The results depend on neither.
    """
    if spectra.n_channels != steering.n_mics:
        raise ValueError(f"the CSM has {spectra.n_channels} channels but the steering model "
                         f"{steering.n_mics} microphones")
    if lockstep < 1:
        raise ValueError(f"lockstep {lockstep} must be at least 1 bin")
    options = options or CleanScOptions()
    freqs = spectra.freqs_hz
    runs = np.array_split(np.arange(freqs.size), min(resolve_workers(workers), freqs.size))
    if len(runs) <= 1:
        return _clean_sc_bins(spectra.csm, freqs, steering, options, grid_shape, lockstep)
    jobs = [(spectra.csm[bins], freqs[bins], steering, options, grid_shape, lockstep)
            for bins in runs]
    return [result for part in run_in_processes(_clean_sc_bins, jobs, len(runs))
            for result in part]
