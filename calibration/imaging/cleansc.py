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
B_max sum_m |h_m(x)|^2 |g_m|^2 and times M/(M-1) when the diagonal is removed. That costs one
complex matrix-vector product (G x M) and one real one per iteration. Acoular instead
re-beamforms G_j over the whole grid from new sines and cosines at every iteration; both give
the same map to rounding.

The clean map is the sum of the components only (the residual is not added back), as in
Acoular. Stopping rules (`StopRule`): Acoular's "peak-rise" (stop once the peak exceeds the one
`stop_window` iterations earlier; that last component is kept), Sijtsma's "csm-norm" (stop
before a component that would increase the Frobenius norm of the off-diagonal degraded CSM),
or "none"; always at most `max_iterations` (default 2M) and, optionally, when the peak falls
`min_peak_db` below the first one.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from .beamform import beamform_csm, diagonal_norm
from .csm import CrossSpectra
from .peaks import subgrid_peak
from .steering import SteeringModel


def _single_threaded_blas() -> contextlib.AbstractContextManager:
    """BLAS on one thread for the CLEAN-SC loop, when threadpoolctl is installed.

    The loop makes thousands of memory-bound BLAS calls of about 0.1 ms each. A second BLAS
    thread gains little there, and on a loaded machine an OpenBLAS thread spins waiting for
    a descheduled partner: a 3534 x 72 zgemv took 0.90 ms on 2 threads against 0.07 ms on 1
    (load 5.8 on 2 cores). Without threadpoolctl the BLAS keeps its own setting
    (OPENBLAS_NUM_THREADS).
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


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


def _offdiag_norms(d: np.ndarray) -> np.ndarray:
    """Frobenius norms (F,) of the off-diagonal parts of matrices d (F, M, M)."""
    total = np.sum((d * d.conj()).real, axis=(1, 2))
    diagonal = np.diagonal(d, axis1=1, axis2=2)
    return np.sqrt(np.maximum(total - np.sum((diagonal * diagonal.conj()).real, axis=1), 0.0))


def _coherence(d: np.ndarray, w: np.ndarray, peak: np.ndarray, options: CleanScOptions
               ) -> np.ndarray:
    """Source vectors g (F, M) of the components at steering w (F, M) with peaks (F,) of the
    degraded CSMs d (F, M, M) (see the module docstring); all bins at once."""
    dw = (d @ w[:, :, None])[:, :, 0]
    if not options.remove_diagonal:
        return dw / peak[:, None]
    d1 = (dw - np.diagonal(d, axis1=1, axis2=2) * w) / peak[:, None]
    w_power = (w * w.conj()).real
    g = w
    for _ in range(options.coherence_iterations):
        g_power = (g * g.conj()).real
        g = d1 + g_power * w
        g /= np.sqrt(1.0 + np.einsum("fm,fm->f", w_power, g_power))[:, None]
    return g


def clean_sc(csm: np.ndarray, h: np.ndarray, options: CleanScOptions | None = None,
             h_power: np.ndarray | None = None, grid_shape: tuple[int, int] | None = None
             ) -> CleanScResult:
    """CLEAN-SC of one CSM (M, M) with steering vectors h (G, M).

    Args:
        h_power: |h|^2 (G, M) if known (frequency-independent); computed otherwise.
        grid_shape: (n_u, n_v) when the G points form a grid (u slowest): each component then
            records the sub-grid position of its dirty-map peak.
    """
    power = h_power if h_power is not None else h.real**2 + h.imag**2
    return clean_sc_bins(np.asarray(csm)[None], h[None], power, options, grid_shape)[0]


def clean_sc_bins(csms: np.ndarray, hs: np.ndarray, h_power: np.ndarray,
                  options: CleanScOptions | None = None,
                  grid_shape: tuple[int, int] | None = None) -> list[CleanScResult]:
    """CLEAN-SC of F CSMs (F, M, M) with their steering vectors hs (F, G, M), side by side.

    The bins are independent; running their iterations together shares the small per-
    iteration work (peak search, source vectors, the diagonal term, which is one real
    product (G, M) x (M, F) since |h|^2 = h_power (G, M) does not depend on frequency) across
    bins. A bin leaves the loop when its own stopping rule fires.
    """
    options = options or CleanScOptions()
    n_bins, n_points, m = hs.shape
    if csms.shape != (n_bins, m, m) or h_power.shape != (n_points, m):
        raise ValueError(f"CSMs {csms.shape}, steering {hs.shape} and |h|^2 {h_power.shape} "
                         "do not match: expected (F, M, M), (F, G, M) and (G, M)")
    dirty = np.stack([beamform_csm(hs[f], csms[f], options.remove_diagonal, h_power)
                      for f in range(n_bins)])
    degraded = np.array(csms, dtype=np.complex128, copy=True)
    clean = np.zeros((n_bins, n_points))
    components: list[list[Component]] = [[] for _ in range(n_bins)]
    csm_norm = _offdiag_norms(degraded)
    norm = diagonal_norm(m, options.remove_diagonal)
    gain = options.loop_gain
    n_max = options.max_iterations or 2 * m
    peaks = np.zeros((n_bins, n_max))
    floors = np.zeros(n_bins)
    active = np.arange(n_bins)
    with _single_threaded_blas():
        for j in range(n_max):
            index = np.argmax(dirty[active], axis=1)
            peak = dirty[active, index]
            if j == 0 and options.min_peak_db is not None:
                floors = peak * 10 ** (-options.min_peak_db / 10)
            go = (peak > 0) & (peak >= floors[active])
            w = np.sqrt(norm) * hs[active, index]
            g = _coherence(degraded[active], w, peak, options)
            source = peak[:, None, None] * g[:, :, None] * g.conj()[:, None, :]
            if options.stop_rule is StopRule.CSM_NORM:
                new_norm = _offdiag_norms(degraded[active] - gain * source)
                go &= new_norm < csm_norm[active]
                csm_norm[active[go]] = new_norm[go]
            active, index, peak, g, source = active[go], index[go], peak[go], g[go], source[go]
            if active.size == 0:
                break
            for f, i, p, gf in zip(active, index, peak, g, strict=True):
                subgrid = subgrid_peak(dirty[f], grid_shape, int(i)) if grid_shape else None
                components[f].append(Component(int(i), gain * float(p), float(p), subgrid, gf))
                clean[f, i] += gain * p
            peaks[active, j] = peak
            if options.stop_rule is StopRule.PEAK_RISE and j > options.stop_window:
                go = peak <= peaks[active, j - options.stop_window]  # a rise: kept, then stop
                active, peak, g, source = active[go], peak[go], g[go], source[go]
                if active.size == 0:
                    break
            beam = np.empty((active.size, n_points))
            for k, f in enumerate(active):
                projection = (hs[f] @ g[k].conj()).view(np.float64).reshape(-1, 2)
                np.einsum("gk,gk->g", projection, projection, out=beam[k])  # |h(x)^H g|^2
            if options.remove_diagonal:
                beam -= (h_power @ (g * g.conj()).real.T).T
            dirty[active] -= (gain * norm * peak)[:, None] * beam
            degraded[active] -= gain * source
    return [CleanScResult(clean[f], dirty[f], components[f]) for f in range(n_bins)]


def clean_sc_spectra(spectra: CrossSpectra, steering: SteeringModel,
                     options: CleanScOptions | None = None,
                     grid_shape: tuple[int, int] | None = None, bins_per_batch: int = 4
                     ) -> list[CleanScResult]:
    """CLEAN-SC at every frequency of `spectra`; sum the clean maps for a band map.

    Up to bins_per_batch bins run side by side (`clean_sc_bins`), holding their steering
    vectors at once (bins_per_batch * G * M * 16 bytes). Few bins keep the steering vectors
    in the processor's cache for the matrix-vector products; more bins share more of the
    per-iteration work. 4 was fastest for 72 microphones and 101 x 101 points on a 2-core
    machine with a 32 MB cache (benchmarks/bench_imaging.py).
    """
    if spectra.n_channels != steering.n_mics:
        raise ValueError(f"the CSM has {spectra.n_channels} channels but the steering model "
                         f"{steering.n_mics} microphones")
    if bins_per_batch < 1:
        raise ValueError(f"bins_per_batch {bins_per_batch} must be >= 1")
    power = steering.amplitude**2
    results: list[CleanScResult] = []
    vectors = steering.vectors_at(spectra.freqs_hz)
    for start in range(0, spectra.freqs_hz.size, bins_per_batch):
        stop = min(start + bins_per_batch, spectra.freqs_hz.size)
        hs = np.stack([next(vectors) for _ in range(start, stop)])
        results += clean_sc_bins(spectra.csm[start:stop], hs, power, options, grid_shape)
    return results
