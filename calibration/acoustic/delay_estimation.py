"""Time-of-flight estimation from reference and array recordings (paper section IV-F).

Each speaker's burst is recorded once by a reference microphone a known distance d_ref
(about 2 mm) from the speaker and once by every array microphone. The delay of an array
channel relative to the reference recording is the argmax of their cross-correlation; the
time of flight from the speaker is that delay plus d_ref / c (`tof_from_delay`).

Why not a 3-point parabola: the correlation of a band-limited signal is a sinc-like peak
sampled at about two samples per main lobe, and a parabola through three samples is biased
by up to ~0.03 sample (0.3 us at 96 kHz, 0.1 mm of range) in the speaker band and ~0.12 sample
at full band. Here the integer peak only seeds Newton iterations on the exact band-limited
interpolant of the correlation,

    r(tau) = sum_k W_k Y_k X_k^* exp(+j 2 pi k tau / N)       (k over the band's rFFT bins),

whose derivatives are analytic. This is the maximum-likelihood delay for white noise and
W_k = 1; it is unbiased for any fractional delay and reaches the Cramer-Rao bound
(`delay_crlb`) above the threshold SNR.

Weightings W_k (`estimate_delays(weighting=...)`; a calibration chooses between the first
two by the session's echo ratio, `TofEstimate.echo_energy`: calibration.pipeline's weighting
"auto"):
- "compact" (the default): the reference deconvolved out, W_k = hann_k / <|X_k|^2> (the
  reference's power spectrum smoothed over 40 Hz), so that the correlation is the relative
  impulse response seen through a Hann window over the band: a pulse whose sidelobes fall
  fast. Why: a reflection arriving 0.2 ms after the direct sound (a table below the array;
  amplitude up to 0.9 of the direct) leaves its correlation tails on the direct peak; with
  the plain band (a brick wall in frequency, tails falling as 1/n) that biased delays by up
  to 0.44 us (96 ns RMS) in the simulated room, with this pulse 12 ns RMS. It costs a
  little precision in white noise: 5.0 ns where the Cramer-Rao bound is 4.0 ns (30 dB).
- "matched": W_k = 1, the maximum-likelihood delay in free field (reaches the bound).
- "phat": W_k = 1 / |Y_k X_k^*| (GCC-PHAT).

The correlation is circular over `n_fft` samples (default: the recording length). That is
exact for a periodic MLS in steady state (one period of it, n_fft = the period: the
correlation is then the periodic impulse response) and for bursts followed by silence longer
than the largest delay; otherwise pass a larger `n_fft` to zero-pad.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import fft as sfft
from scipy.ndimage import uniform_filter1d

from ..errors import CalibrationInputError

Weighting = Literal["compact", "matched", "phat"]

# Working-set budget (elements of the largest (chunk, channel, bin) array) per batch, so
# that thousands of recordings of 72 channels do not need gigabytes at once.
_CHUNK_ELEMENTS = 8_000_000
_NEWTON_ITERATIONS = 8
_NEWTON_TOL_SAMPLES = 1e-4
"""A channel leaves Newton's iterations after a step below this (samples): the iteration
converges quadratically, so what is left after such a step is of its square, 1e-8 sample."""
_PHASOR_BLOCK = 64  # bins per block of `_BandSums`
_GAIN_BLOCKS = 4
"""`_BandSums` blocks per sub-band of `_quality`'s gain (256 bins: 1.5 kHz for an order-14 MLS
at 96 kHz). Narrow enough to follow a speaker's off-axis roll-off, wide enough to leave a
room reflection's ripple (a period of 3 kHz or less) in the residual, where it counts as the
noise it is for a delay."""
_SINC_HALF_WIDTH = 24
"""Lags either side of the integer peak that the time-domain start (`_sinc_peak`) uses."""
IMPULSE_HALF_WIDTH_S = 1e-3
"""Half-width of the correlation kept around every direct peak (`TofEstimate.impulses`)."""
ECHO_SPAN_S = (1.5e-4, 2e-2)
"""(start, end) in seconds from the direct peak of the span whose correlation energy after
the peak (`TofEstimate.echo_energy`) is compared with that before it (`lead_energy`). It
starts just past the compact pulse's main lobe (its first zero is 0.1 ms from the peak for
the 0.3-20 kHz band; at 0.15 ms its energy is down to 1e-4 of the peak's, and where the lag
grid samples it off centre the excess on one side is matched by one on the other over
many measurements), so that a table's reflection 0.2 ms behind the direct sound counts. It
ends at 20 ms (7 m of extra path), beyond which a reflection biases a matched-weighting
delay by under 10 ns per unit of its amplitude."""
_COMPACT_SMOOTHING_HZ = 40.0
"""Width of the moving average of the reference's power spectrum that "compact" divides by
(about 7 x fs / burst length for an order-14 MLS at 96 kHz): it keeps the dips of a burst's
spectrum from amplifying the noise, and leaves the pulse compact (measured on the simulated
room: 4 / 8 / 16 / 32 bins of 4.9 Hz gave 13.9 / 12.0 / 18.7 / 30 ns RMS with the room,
5.0 / 5.0 / 4.9 / 4.9 ns in white noise, where the bound is 4.0 ns)."""


@dataclass(frozen=True)
class TofEstimate:
    """Delays of array channels relative to their reference recordings.

    Attributes:
        delay_s: (n_rec, n_ch) delay in seconds (array-channel arrival minus reference arrival).
        std_s: (n_rec, n_ch) predicted standard deviation of the delay in seconds: the
            Cramer-Rao bound evaluated with this measurement's own fitted signal and residual
            noise spectra (assumed white within the band). Suitable as the solver's sigma.
        snr_db: (n_rec, n_ch) in-band SNR: energy of the delayed, scaled reference that best
            explains the channel over the energy left unexplained, in dB.
        peak_to_sidelobe_db: (n_rec, n_ch) correlation peak over the largest |correlation|
            farther than `sidelobe_guard_s` from the peak, in dB. Low values flag reflections
            or interference of similar strength to the direct path.
        impulses: (n_rec, n_ch, n_lag) float32, the weighted correlation around the direct
            peak (+-`IMPULSE_HALF_WIDTH_S`): with the "compact" weighting, the relative impulse
            response seen through the band's window. What the microphones' responses are
            estimated from once the geometry is known (calibration.acoustic.responses), without
            reading the recordings again.
        impulse_first_lag: (n_rec, n_ch) the full-rate lag (samples, signed) of impulses[..., 0].
        impulse_step: full-rate samples between the impulses' values (about 2, or 1 for a
            band reaching above a quarter of the sample rate).
        echo_energy: (n_rec, n_ch) the correlation's energy (sum of squares over its lags)
            over `ECHO_SPAN_S` after the direct peak: reflections, a capsule's ringing and
            noise.
        lead_energy: (n_rec, n_ch) the same over the span as far before the peak, where
            nothing arrives and only noise is (with periodic bursts, the previous period's
            late reverberation too). Pooled over a session, echo over lead energy is 1 in free
            field with flat capsules, and far above 1 in a room (`SessionTofs.echo_ratio`).
    """

    delay_s: np.ndarray
    std_s: np.ndarray
    snr_db: np.ndarray
    peak_to_sidelobe_db: np.ndarray
    impulses: np.ndarray
    impulse_first_lag: np.ndarray
    impulse_step: float
    echo_energy: np.ndarray
    lead_energy: np.ndarray


def band_bins(n_fft: int, fs: float, band: tuple[float, float]) -> np.ndarray:
    """Indices of the rFFT bins inside `band` (Hz), excluding DC and the Nyquist bin.

    DC carries no delay information and the Nyquist bin of a real signal cannot represent a
    fractional delay, so both are always left out.
    """
    k = np.arange(n_fft // 2 + 1)
    f = k * fs / n_fft
    keep = (f >= band[0]) & (f <= band[1]) & (k > 0) & (2 * k != n_fft)
    if not keep.any():
        raise CalibrationInputError(f"band {band} Hz holds no rFFT bin for n_fft={n_fft}, fs={fs}")
    return k[keep]


def estimate_delays(
    recordings: np.ndarray,
    references: np.ndarray,
    fs: float,
    band: tuple[float, float] = (300.0, 20000.0),
    weighting: Weighting = "compact",
    delay_window_s: tuple[float, float] | None = None,
    n_fft: int | None = None,
    sidelobe_guard_s: float = 5e-4,
    first_arrival: float = 0.5,
    fft_workers: int = -1,
) -> TofEstimate:
    """Delay of every array channel relative to its recording's reference, batched.

    Args:
        recordings: (n_rec, n_ch, n_samples) array-microphone recordings, one per burst.
        references: (n_rec, n_samples) the reference-microphone recording of the same burst.
        fs: sample rate in Hz.
        band: (f_lo, f_hi) in Hz: only these bins enter the correlation (the speaker band; out
            of band there is only noise).
        weighting: the correlation's spectral weighting (module docstring): "compact"
            (robust to early reflections), "matched" (maximum likelihood in free field) or
            "phat" (GCC-PHAT).
        delay_window_s: (min, max) delay in seconds searched for the peak; None searches all
            circular lags in [-n_fft/2, n_fft/2). Use it to gate out late reflections.
        n_fft: correlation length (>= n_samples); see the module docstring.
        sidelobe_guard_s: half-width in seconds of the main lobe excluded from the
            peak-to-sidelobe ratio.
        first_arrival: the delay is that of the earliest correlation peak in the window that
            reaches this fraction of the window's highest one (the direct sound arrives first;
            a reflection can be stronger); 1 takes the highest peak.
        fft_workers: threads of each FFT (scipy.fft's `workers`; -1: every core). A caller
            that runs several estimates at once on threads gives 1: more threads than cores
            cost it a sixth of its time.

    Returns:
        TofEstimate with (n_rec, n_ch) arrays.

    The polarity of every channel is assumed positive (the positive correlation peak is
    sought).
    """
    # float32 stays float32 through the FFTs (a session's 16-bit codes are exact in it, and
    # its rounding is 1e-7 of the signal, far below any noise); the band's bins are then
    # worked in double precision
    recordings = np.asarray(recordings)
    references = np.asarray(references)
    if recordings.dtype != np.float32 or references.dtype != np.float32:
        recordings = recordings.astype(np.float64, copy=False)
        references = references.astype(np.float64, copy=False)
    if recordings.ndim != 3 or references.ndim != 2:
        raise ValueError("recordings must be (n_rec, n_ch, n), references (n_rec, n)")
    n_rec, n_ch, n_samples = recordings.shape
    if references.shape != (n_rec, n_samples):
        raise ValueError(
            f"references {references.shape} do not match recordings {recordings.shape}"
        )
    n_fft = n_samples if n_fft is None else int(n_fft)
    if n_fft < n_samples:
        raise ValueError("n_fft must be >= the number of samples")
    bins = band_bins(n_fft, fs, band)
    lags = _Lags.of(n_fft, fs, bins, delay_window_s, sidelobe_guard_s)

    chunk = max(1, _CHUNK_ELEMENTS // (n_ch * n_fft))
    parts = [
        _estimate_chunk(
            recordings[i : i + chunk],
            references[i : i + chunk],
            fs,
            bins,
            n_fft,
            weighting,
            lags,
            first_arrival,
            fft_workers,
        )
        for i in range(0, n_rec, chunk)
    ]
    delay, std, snr, psr, impulses, first_lag, echo, lead = (
        np.concatenate(field) for field in zip(*parts, strict=True))
    return TofEstimate(delay, std, snr, psr, impulses, first_lag, impulse_step=lags.step,
                       echo_energy=echo, lead_energy=lead)


@dataclass(frozen=True)
class _Lags:
    """The equally spaced lags the peak is sought on.

    The correlation is band-limited, so when the band's top lies below a quarter of the
    sample rate (20 kHz at 96 kS/s), about every second lag describes it completely: the peak
    is sought on a correlation of a fast FFT length near half the circle's (`step` = n_fft /
    length, 2 for an even n_fft, just under 2 for the odd period of an MLS, whose own length
    is a slow one), a quarter of the inverse FFT's work, and Newton's method refines it at
    the full rate.

    Attributes:
        step: full-rate samples per lag (n_fft / length).
        length: number of lags.
        window: (length,) lags allowed for the peak.
        guard: half-width of the main lobe, in lags.
    """

    step: float
    length: int
    window: np.ndarray
    guard: int

    @classmethod
    def of(cls, n_fft: int, fs: float, bins: np.ndarray,
           delay_window_s: tuple[float, float] | None, sidelobe_guard_s: float) -> _Lags:
        half = n_fft // 2 if n_fft % 2 == 0 else sfft.next_fast_len((n_fft + 1) // 2, real=True)
        length = half if 2 * int(bins.max()) < half < n_fft else n_fft
        step = n_fft / length
        lags = np.arange(length)
        lags = step * np.where(lags >= (length + 1) // 2, lags - length, lags)
        if delay_window_s is None:
            window = np.ones(length, dtype=bool)
        else:
            lo, hi = (d * fs for d in delay_window_s)
            window = (lags >= np.floor(lo) - step + 1) & (lags <= np.ceil(hi) + step - 1)
            if not window.any():
                raise CalibrationInputError(f"delay window {delay_window_s} s holds no lag")
        return cls(step, length, window, int(np.ceil(sidelobe_guard_s * fs / step)))


def _estimate_chunk(
    rec: np.ndarray,
    ref: np.ndarray,
    fs: float,
    bins: np.ndarray,
    n_fft: int,
    weighting: Weighting,
    lags: _Lags,
    first_arrival: float,
    fft_workers: int,
) -> tuple[np.ndarray, ...]:
    """estimate_delays on a chunk of recordings; returns (delay, std, snr_db, psr_db,
    impulses, impulse_first_lag, echo_energy, lead_energy)."""
    # single precision stays single (1e-7 of rounding: a thousandth of a nanosecond of delay)
    # a band's consecutive bins as a slice: a view of the spectrum, not a copy of it
    band = (slice(int(bins[0]), int(bins[-1]) + 1) if np.all(np.diff(bins) == 1) else bins)
    X = sfft.rfft(ref, n_fft, axis=-1, workers=fft_workers)[:, None, band]
    Y = sfft.rfft(rec, n_fft, axis=-1, workers=fft_workers)[..., band]
    cross = Y * np.conj(X)
    weighted = _weighted(cross, X, weighting,
                         max(1, round(_COMPACT_SMOOTHING_HZ * n_fft / fs)))

    corr = _lag_correlation(weighted, band, lags.length, fft_workers)
    peak = _first_arrival(corr, lags.window, first_arrival)
    psr_db = _peak_to_sidelobe_db(corr, peak, lags.guard)

    start = peak + _parabolic_offset(corr, peak)
    start = np.where(start >= (lags.length + 1) // 2, start - lags.length, start)
    start = lags.step * _sinc_peak(corr, start, _SINC_HALF_WIDTH)
    tau = _newton_peak(weighted, bins, n_fft, start)

    std_s, snr_db = _quality(X, Y, cross, bins, n_fft, tau, fs)
    half = int(np.ceil(IMPULSE_HALF_WIDTH_S * fs / lags.step))
    around = peak[..., None] + np.arange(-half, half + 1)
    impulses = np.take_along_axis(corr, around % lags.length, axis=-1).astype(np.float32)
    signed = np.where(peak >= (lags.length + 1) // 2, peak - lags.length, peak)
    echo, lead = _echo_and_lead_energy(corr, peak, lags, fs)
    return (tau / fs, std_s, snr_db, psr_db, impulses, lags.step * (signed - half), echo,
            lead)


def _echo_and_lead_energy(corr: np.ndarray, peak: np.ndarray, lags: _Lags, fs: float
                          ) -> tuple[np.ndarray, np.ndarray]:
    """The correlation's energy (...) over `ECHO_SPAN_S` after the peak and over the span as
    far before it (circular; the span is cut to under half the circle, so the two never
    overlap). Each span is a window of a circularly padded copy of the correlation, and its
    sum of squares is accumulated in the correlation's own precision (single: 1e-5 of it,
    plenty for a ratio judged at 2 %): faster than gathering the spans by index
    (benchmarks/bench_calibration.py times the stage)."""
    first, last = (int(round(t * fs / lags.step)) for t in ECHO_SPAN_S)
    last = min(last, (lags.length - 1) // 2)
    rows = corr.reshape(-1, lags.length)
    padded = np.concatenate([rows[:, lags.length - last:], rows, rows[:, :last + 1]], axis=1)
    spans = sliding_window_view(padded, last - first + 1, axis=1)  # spans[r, i]: from i - last
    row = np.arange(rows.shape[0])
    at = peak.ravel()
    after = spans[row, at + last + first]
    before = spans[row, at]
    return (np.einsum("rl,rl->r", after, after).astype(np.float64).reshape(peak.shape),
            np.einsum("rl,rl->r", before, before).astype(np.float64).reshape(peak.shape))


def _first_arrival(corr: np.ndarray, window: np.ndarray, fraction: float) -> np.ndarray:
    """Lag index (...) of the earliest local maximum inside `window` that reaches `fraction`
    of the window's largest correlation: the direct sound, which arrives first even when a
    reflection is stronger (a speaker turned away from a microphone radiates more towards a
    table than towards it). fraction = 1 picks the largest peak."""
    n = corr.shape[-1]
    lags = np.arange(n)
    order = np.argsort(np.where(lags >= (n + 1) // 2, lags - n, lags)[window], kind="stable")
    index = np.flatnonzero(window)[order]  # window's lag indices, earliest first
    values = corr[..., index]
    top = values.max(axis=-1, keepdims=True)
    left = corr[..., (index - 1) % n]
    right = corr[..., (index + 1) % n]
    candidate = (values >= fraction * top) & (values >= left) & (values >= right)
    return index[np.argmax(candidate, axis=-1)]


def _weighted(cross: np.ndarray, X: np.ndarray, weighting: Weighting,
              smoothing_bins: int) -> np.ndarray:
    """The cross-spectrum (..., K) with the weighting W_k of the module docstring
    (`smoothing_bins`: the width of the moving average of |X_k|^2 for "compact")."""
    tiny = np.finfo(float).tiny
    if weighting == "matched":
        return cross
    if weighting == "phat":
        return cross / np.maximum(np.abs(cross), tiny)
    if weighting == "compact":
        k = cross.shape[-1]
        hann = 0.5 - 0.5 * np.cos(2.0 * np.pi * (np.arange(k) + 0.5) / k)
        power = uniform_filter1d(X.real**2 + X.imag**2, smoothing_bins, axis=-1, mode="nearest")
        scale = np.mean(power, axis=-1, keepdims=True)  # keeps the values' magnitude
        weight = hann * scale / np.maximum(power, tiny * scale + tiny)
        return cross * weight.astype(power.dtype)  # single precision stays single
    raise CalibrationInputError(f"unknown weighting {weighting!r}; choose compact, matched or phat")


def _lag_correlation(weighted: np.ndarray, band: slice | np.ndarray, length: int,
                     fft_workers: int) -> np.ndarray:
    """The band-limited correlation at `length` equally spaced lags around the circle (r, ch,
    length): every full-rate lag (length n_fft) or about every second one (the band's bins
    then all below the shorter circle's Nyquist bin, so that it is sampled exactly). `band`:
    the bins of `weighted`, a slice where they are consecutive (a slice's assignment is
    several times faster than an index array's)."""
    full = np.zeros((*weighted.shape[:-1], length // 2 + 1), dtype=np.complex64)
    full[..., band] = weighted
    return sfft.irfft(full, length, axis=-1, workers=fft_workers)


def _parabolic_offset(corr: np.ndarray, peak: np.ndarray) -> np.ndarray:
    """Vertex of the parabola through the peak and its neighbours, clipped to +-0.5 sample.

    Only a starting point for Newton: its bias (a few hundredths of a sample) is removed by
    the iterations on the exact interpolant.
    """
    n = corr.shape[-1]
    take = lambda idx: np.take_along_axis(corr, (idx % n)[..., None], axis=-1)[..., 0]  # noqa: E731
    left, mid, right = take(peak - 1), take(peak), take(peak + 1)
    denom = left - 2.0 * mid + right
    offset = np.where(denom < 0, 0.5 * (left - right) / np.where(denom < 0, denom, -1.0), 0.0)
    return np.clip(offset, -0.5, 0.5)


def _sinc_peak(corr: np.ndarray, start: np.ndarray, half_width: int) -> np.ndarray:
    """The peak (in lags) of the correlation's sinc interpolation through the 2 half_width
    + 1 lags around `start`, by Newton's method: the start of the exact refinement.

    Why: the exact band-limited interpolant sums over every bin of the band (thousands) at
    each iteration; this one over a few dozen lags. Truncated, it is only close to the exact
    peak (well within a hundredth of a sample for a compact pulse), so the exact refinement
    after it needs one or two iterations instead of four or five.
    """
    n = corr.shape[-1]
    flat = corr.reshape(-1, n)
    x = np.asarray(start, dtype=np.float64).ravel().copy()
    lags = np.round(x).astype(np.int64)[:, None] + np.arange(-half_width, half_width + 1)
    samples = np.take_along_axis(flat, lags % n, axis=1).astype(np.float64)
    for _ in range(_NEWTON_ITERATIONS):
        _, d1, d2 = _sinc_derivatives(x[:, None] - lags)
        r1, r2 = np.sum(samples * d1, axis=1), np.sum(samples * d2, axis=1)
        step = np.where(r2 < 0, -r1 / np.where(r2 < 0, r2, -1.0), 0.5 * np.sign(r1))
        step = np.clip(step, -0.5, 0.5)
        x += step
        if np.all(np.abs(step) < 1e-4):
            break
    return x.reshape(np.shape(start))


def _sinc_derivatives(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """sinc(d) = sin(pi d) / (pi d) and its first two derivatives (series near d = 0; the
    second from d f'' + 2 f' + pi^2 d f = 0)."""
    small = np.abs(d) < 1e-4
    safe = np.where(small, 1.0, d)
    pd = np.pi * safe
    f = np.where(small, 1.0 - (np.pi * d) ** 2 / 6.0, np.sin(pd) / pd)
    f1 = np.where(small, -(np.pi**2) * d / 3.0, (np.cos(pd) - f) / safe)
    f2 = np.where(small, -(np.pi**2) / 3.0 * (1.0 - (np.pi * d) ** 2 / 10.0),
                  -(np.pi**2) * f - 2.0 * f1 / safe)
    return f, f1, f2


class _BandSums:
    """The sums over a band's bins S_p(tau) = sum_k C_k exp(j omega_k tau) omega_k^p, p = 0, 1,
    2 (the correlation at tau and, times j and -1, its first two derivatives), for one tau
    per row of coefficients C (rows, K), omega_k = 2 pi bins_k / n_fft rad per sample.

    For consecutive bins (a band) k = k_0 + a B + b, and exp(j omega_k tau) = exp(j u_a tau)
    exp(j v_b tau) with u_a = w (k_0 + a B), v_b = w b, w = 2 pi / n_fft; omega_k = u_a + v_b,
    so that, with s_{a,q} = sum_b C_{a,b} exp(j v_b tau) v_b^q (one batched product of the
    coefficients, seen as (rows, A, B) without a copy, with a (rows, B, 3) table; the last
    K mod B bins are summed directly),

        S_0 = sum_a e_a s_{a,0},  S_1 = sum_a e_a (u_a s_{a,0} + s_{a,1}),
        S_2 = sum_a e_a (u_a^2 s_{a,0} + 2 u_a s_{a,1} + s_{a,2}),  e_a = exp(j u_a tau).

    Why: Newton's iterations need S_1 and S_2 at every step; forming the (rows, K) phasors and
    their products with C took five passes over the band per step, this takes one (with the
    band taken as a view; benchmarks/bench_calibration.py times the stage). The exponentials
    are exact (no recurrence); the block products are in C's
    precision, their sum over blocks in double.
    """

    def __init__(self, coeffs: np.ndarray, bins: np.ndarray, n_fft: int) -> None:
        w = 2.0 * np.pi / n_fft
        k = bins.size
        block = _PHASOR_BLOCK
        n_blocks = k // block
        self.blocked = n_blocks >= 1 and bool(np.all(np.diff(bins) == 1))
        # the last k mod B bins, and any band of other bins, are summed directly
        tail = n_blocks * block if self.blocked else 0
        self.rest = coeffs[:, tail:]
        self.omega = w * bins[tail:].astype(np.float64)
        if self.blocked:  # a view: each row's first n_blocks * B coefficients as (A, B)
            rows = coeffs.shape[0]
            self.coeffs = np.lib.stride_tricks.as_strided(
                coeffs, (rows, n_blocks, block),
                (coeffs.strides[0], block * coeffs.strides[1], coeffs.strides[1]),
                writeable=False)
            self.u = w * (bins[0] + block * np.arange(n_blocks, dtype=np.float64))
            self.v = w * np.arange(block, dtype=np.float64)

    def keep(self, rows: np.ndarray) -> None:
        """Keep only these rows (the channels still iterating)."""
        self.rest = self.rest[rows]
        if self.blocked:
            self.coeffs = self.coeffs[rows]

    def sub_band_sums(self, tau: np.ndarray, blocks: int) -> np.ndarray:
        """(rows, n_sub) complex128: S_0 over each run of `blocks` consecutive blocks (the
        last run takes the blocks left over and the last K mod B bins); one column, S_0 of the
        whole band, if the bins are not blocked."""
        if not self.blocked:
            return self.sums(tau, orders=1)
        t = np.asarray(tau, dtype=np.float64)[:, None]
        fine = np.exp(1j * self.v * t).astype(self.coeffs.dtype)  # (rows, B)
        per_block = np.matmul(self.coeffs, fine[:, :, None])[:, :, 0].astype(np.complex128)
        per_block *= np.exp(1j * self.u * t)
        starts = np.arange(0, per_block.shape[1], blocks)
        if starts.size > 1 and per_block.shape[1] - starts[-1] < blocks:
            starts = starts[:-1]  # a short last run joins the one before it
        out = np.add.reduceat(per_block, starts, axis=1)
        if self.omega.size:
            out[:, -1] += np.sum(self.rest * np.exp(1j * self.omega * t), axis=1)
        return out

    def sub_band_starts(self, n_bins: int, blocks: int) -> np.ndarray:
        """Index of the first bin of each of `sub_band_sums`' sub-bands (for np.add.reduceat
        over the band's bins)."""
        if not self.blocked:
            return np.zeros(1, dtype=int)
        n_blocks = n_bins // _PHASOR_BLOCK
        starts = np.arange(0, n_blocks, blocks)
        if starts.size > 1 and n_blocks - starts[-1] < blocks:
            starts = starts[:-1]
        return starts * _PHASOR_BLOCK

    def sums(self, tau: np.ndarray, orders: int = 3) -> np.ndarray:
        """(rows, orders) complex128: S_0 .. S_{orders-1} at tau (rows,) samples."""
        t = np.asarray(tau, dtype=np.float64)[:, None]
        out = np.zeros((t.shape[0], orders), dtype=np.complex128)
        if self.omega.size:
            z = self.rest * np.exp(1j * self.omega * t).astype(self.rest.dtype)
            for p in range(orders):
                out[:, p] = z @ self.omega**p
        if not self.blocked:
            return out
        fine = np.exp(1j * self.v * t)  # (rows, B)
        table = fine[:, :, None] * self.v[None, :, None] ** np.arange(orders)  # (rows, B, q)
        s = np.matmul(self.coeffs, table.astype(self.coeffs.dtype)).astype(np.complex128)
        e = np.exp(1j * self.u * t)  # (rows, A)
        u = self.u
        out[:, 0] += np.einsum("ra,ra->r", e, s[..., 0])
        if orders > 1:
            out[:, 1] += np.einsum("ra,ra->r", e, u * s[..., 0] + s[..., 1])
        if orders > 2:
            out[:, 2] += np.einsum("ra,ra->r", e, u**2 * s[..., 0] + 2.0 * u * s[..., 1]
                                   + s[..., 2])
        return out


def _newton_peak(weighted: np.ndarray, bins: np.ndarray, n_fft: int, tau: np.ndarray
                 ) -> np.ndarray:
    """Maximise r(tau) = Re sum_k C_k exp(j omega_k tau) by Newton's method (tau in samples):
    r' = -Im S_1, r'' = -Re S_2 (`_BandSums`).

    Steps are clipped to half a sample; where the curvature is not negative (far from a
    peak) a half-sample step uphill is taken instead, so the iteration cannot run to a
    minimum. Converges quadratically from a start near the peak; a channel leaves the
    iterations after a step below `_NEWTON_TOL_SAMPLES`.
    """
    shape = tau.shape
    tau = tau.astype(np.float64).ravel()
    band = _BandSums(weighted.reshape(tau.size, -1), bins, n_fft)
    active = np.arange(tau.size)
    for _ in range(_NEWTON_ITERATIONS):
        sums = band.sums(tau[active])
        d1, d2 = -sums[:, 1].imag, -sums[:, 2].real
        step = np.where(d2 < 0, -d1 / np.where(d2 < 0, d2, -1.0), 0.5 * np.sign(d1))
        step = np.clip(step, -0.5, 0.5)
        tau[active] += step
        going = np.abs(step) >= _NEWTON_TOL_SAMPLES
        if not going.any():
            break
        if not going.all():
            active = active[going]
            band.keep(going)
    return tau.reshape(shape)


def _quality(
    X: np.ndarray, Y: np.ndarray, cross: np.ndarray, bins: np.ndarray, n_fft: int,
    tau: np.ndarray, fs: float
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted delay std (s) and in-band SNR (dB) from the unweighted fit at `tau`.

    The channel is modelled in band as Y_k = g_b X_k exp(-j omega_k tau) + E_k, with one real
    gain g_b per sub-band b of the band (`_GAIN_BLOCKS`). The least-squares gain is
    g_b = r_b / E_x,b with r_b = Re sum_(k in b) Y_k X_k^* exp(j omega_k tau); the residual
    energy is the sum over sub-bands of E_y,b - r_b^2 / E_x,b. With the residual taken as
    white in band (per-bin power sigma_E^2 = residual / (K - n_sub)) the bound of
    `delay_crlb` is evaluated with signal power g_b^2 |X_k|^2. The residual contains the
    reference's noise (scaled by g) too, as it should.

    Why a gain per sub-band: a speaker's off-axis roll-off (its directivity), a capsule's
    resonance or the air's absorption tilt the channel's spectrum against the reference's. One
    gain for the band counted that tilt as noise: on the simulated lab with the speakers'
    directivity the predicted std grew 18-fold from 0-10 to 50-60 degrees off the speaker's
    axis while the delays' actual error doubled, and the joint fit, weighting by it, all but
    dropped the off-axis sources (the microphones' errors relative to the array 1.7 times
    their reported sigma; about their sigma with a gain per sub-band).
    """
    omega = 2.0 * np.pi * bins / n_fft  # rad per sample
    band = _BandSums(cross.reshape(tau.size, -1), bins, n_fft)
    r = band.sub_band_sums(tau.ravel(), _GAIN_BLOCKS).real.reshape(*tau.shape, -1)
    starts = band.sub_band_starts(bins.size, _GAIN_BLOCKS)
    x_power = (X.real**2 + X.imag**2).astype(np.float64)
    ex = np.add.reduceat(x_power, starts, axis=-1)
    ey = np.add.reduceat(Y.real**2 + Y.imag**2, starts, axis=-1, dtype=np.float64)
    ex_omega2 = np.add.reduceat(x_power * (omega * fs) ** 2, starts, axis=-1)
    tiny = np.finfo(float).tiny
    signal_b = np.maximum(r, 0.0) ** 2 / np.maximum(ex, tiny)
    signal = np.sum(signal_b, axis=-1)
    total = np.sum(ey, axis=-1)
    residual = np.maximum(total - signal, tiny * total + tiny)
    noise_per_bin = residual / max(omega.size - starts.size, 1)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        gain2 = signal_b / np.maximum(ex, tiny)
        fisher = 2.0 * np.sum(gain2 * ex_omega2, axis=-1) / noise_per_bin
        std_s = 1.0 / np.sqrt(fisher)
        snr_db = 10.0 * np.log10(signal / residual)
    return std_s, snr_db


def _peak_to_sidelobe_db(corr: np.ndarray, peak: np.ndarray, guard: int) -> np.ndarray:
    """20 log10(peak / max |corr| at circular distance > guard samples from the peak)."""
    n = corr.shape[-1]
    top = np.take_along_axis(corr, peak[..., None], axis=-1)[..., 0]
    magnitude = np.abs(corr)
    if 2 * guard + 1 >= n:
        side = np.zeros(top.shape)
    else:
        # the main lobe, peak - guard .. peak + guard (circular), is left out
        lobe = (peak[..., None] + np.arange(-guard, guard + 1)) % n
        np.put_along_axis(magnitude, lobe, 0.0, axis=-1)
        side = magnitude.max(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return 20.0 * np.log10(np.maximum(top, 0.0) / side)


def tof_from_delay(
    delay_s: np.ndarray, reference_distance_m: float | np.ndarray, speed_of_sound_m_s: float
) -> np.ndarray:
    """Time of flight from the speaker: the delay plus the reference microphone's own flight.

    The delay is measured against the reference microphone, which hears the speaker
    d_ref / c later than the speaker emits. Leaving it out (2 mm ~ 6 us) biases every
    microphone by about 2 mm, so it is an explicit step. `reference_distance_m` broadcasts
    against `delay_s` (e.g. shape (n_rec, 1) for one distance per speaker).
    """
    return np.asarray(delay_s) + np.asarray(reference_distance_m) / speed_of_sound_m_s


def delay_crlb(
    signal_power: np.ndarray,
    noise_power: np.ndarray | float,
    freqs_hz: np.ndarray,
    reference_noise_power: np.ndarray | float = 0.0,
) -> float:
    """Cramer-Rao bound (standard deviation, seconds) of a delay from per-bin spectra.

    Model, per rFFT bin k of an N-point transform (0 < f_k < fs/2, the bins used):
        X_k = S_k + V_k                       (reference channel)
        Y_k = S_k exp(-j 2 pi f_k D) + W_k     (array channel, gain folded into S_k)
    with independent circular complex Gaussian noise, E|W_k|^2 = noise_power,
    E|V_k|^2 = reference_noise_power (white time-domain noise of variance sigma^2 gives
    E|W_k|^2 = N sigma^2), and |S_k|^2 = signal_power, all in the same DFT normalisation.

    With S_k known, each bin is a complex Gaussian with mean S_k exp(-j w_k D) and variance
    P_W, whose Fisher information on D is 2 |dmean/dD|^2 / P_W = 2 w_k^2 |S_k|^2 / P_W. The
    bins are independent, so

        var(D) >= 1 / (2 sum_k (2 pi f_k)^2 SNR_k),   SNR_k = |S_k|^2 / P_W,k.

    (Parseval turns this into the time-domain form sigma^2 / sum_n s'(t_n)^2.) With the signal
    unknown and both channels noisy, eliminating S_k leaves the same form with
    P_W -> P_W + P_V, i.e. SNR_k^-1 = SNR_W^-1 + SNR_V^-1. The bound is asymptotic: it holds
    above the threshold post-correlation SNR, which an MLS of thousands of samples exceeds
    even at 0 dB per-sample SNR.
    """
    snr = np.asarray(signal_power) / (np.asarray(noise_power) + np.asarray(reference_noise_power))
    return float(1.0 / np.sqrt(2.0 * np.sum((2.0 * np.pi * np.asarray(freqs_hz)) ** 2 * snr)))


def delay_crlb_white(
    signal: np.ndarray,
    fs: float,
    noise_std: float,
    band: tuple[float, float] = (300.0, 20000.0),
    reference_noise_std: float = 0.0,
) -> float:
    """`delay_crlb` for a known noise-free signal (as received) in white noise of `noise_std`.

    Only the bins in `band` count, as only they are used by `estimate_delays`.
    """
    signal = np.asarray(signal, dtype=np.float64)
    n = signal.size
    bins = band_bins(n, fs, band)
    power = np.abs(sfft.rfft(signal)[bins]) ** 2
    return delay_crlb(power, n * noise_std**2, bins * fs / n, n * reference_noise_std**2)
