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

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from .beamform import beamform_csm, diagonal_norm
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
    return float(np.sqrt(max(np.sum(np.abs(d) ** 2) - np.sum(np.abs(np.diagonal(d)) ** 2),
                             0.0)))


def _coherence(d: np.ndarray, w: np.ndarray, peak: float, options: CleanScOptions
               ) -> np.ndarray:
    """The source vector g of the component at steering w (see the module docstring)."""
    if not options.remove_diagonal:
        return (d @ w) / peak
    d1 = (d @ w - np.diagonal(d) * w) / peak
    w_power = (w * w.conj()).real
    g = w
    for _ in range(options.coherence_iterations):
        g_power = (g * g.conj()).real
        g = d1 + g_power * w
        g /= np.sqrt(1.0 + w_power @ g_power)
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
    options = options or CleanScOptions()
    m = csm.shape[-1]
    power = h_power if h_power is not None else h.real**2 + h.imag**2
    norm = diagonal_norm(m, options.remove_diagonal)
    dirty = beamform_csm(h, csm, options.remove_diagonal, power)
    degraded = np.array(csm, dtype=np.complex128, copy=True)
    clean = np.zeros(h.shape[0])
    components: list[Component] = []
    peaks: list[float] = []
    n_max = options.max_iterations or 2 * m
    floor = None
    csm_norm = _offdiag_norm(degraded)
    gain = options.loop_gain
    for j in range(n_max):
        index = int(np.argmax(dirty))
        peak = float(dirty[index])
        if floor is None and options.min_peak_db is not None:
            floor = peak * 10 ** (-options.min_peak_db / 10)
        if peak <= 0 or (floor is not None and peak < floor):
            break
        w = np.sqrt(norm) * h[index]
        g = _coherence(degraded, w, peak, options)
        source = peak * np.outer(g, g.conj())
        if options.stop_rule is StopRule.CSM_NORM:
            new_norm = _offdiag_norm(degraded - gain * source)
            if new_norm >= csm_norm:
                break
            csm_norm = new_norm
        subgrid = (subgrid_peak(dirty, grid_shape, index) if grid_shape is not None else None)
        components.append(Component(index, gain * peak, peak, subgrid, g))
        clean[index] += gain * peak
        peaks.append(peak)
        if (options.stop_rule is StopRule.PEAK_RISE and j > options.stop_window
                and peak > peaks[j - options.stop_window]):
            break
        projection = (h @ g.conj()).view(np.float64).reshape(-1, 2)
        beam = np.einsum("gk,gk->g", projection, projection)  # |h(x)^H g|^2
        if options.remove_diagonal:
            beam -= power @ (g * g.conj()).real
        beam *= gain * peak * norm
        dirty -= beam
        degraded -= gain * source
    return CleanScResult(clean, dirty, components)


def clean_sc_spectra(spectra: CrossSpectra, steering: SteeringModel,
                     options: CleanScOptions | None = None,
                     grid_shape: tuple[int, int] | None = None) -> list[CleanScResult]:
    """CLEAN-SC at every frequency of `spectra`; sum the clean maps for a band map."""
    if spectra.n_channels != steering.n_mics:
        raise ValueError(f"the CSM has {spectra.n_channels} channels but the steering model "
                         f"{steering.n_mics} microphones")
    power = steering.amplitude**2
    return [clean_sc(spectra.csm[i], h, options, power, grid_shape)
            for i, h in enumerate(steering.vectors_at(spectra.freqs_hz))]
