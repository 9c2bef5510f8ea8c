"""What the acoustic mistakes do to a signal: a saturating speaker, a close reflection, an
overdriven input stage. Pure functions on volts; sim.mistakes.plan says where they apply."""

from __future__ import annotations

import numpy as np
import scipy.fft

from ..sound import fft_length


def saturated(spectrum: np.ndarray, n_fft: int, drive: float) -> np.ndarray:
    """The rFFT (n_fft) of a speaker's output driven into saturation: its linear output y
    (the drive through the speaker's response, `spectrum`) through L tanh(y / L) with
    L = max|y| / drive. Unit gain for small signals; the peak is compressed to
    tanh(drive) / drive of itself and the rest becomes harmonics (evaluated on the sample grid,
    so harmonics above the Nyquist frequency fold back, as in a sampled model of a speaker)."""
    y = scipy.fft.irfft(spectrum, n=n_fft)
    peak = float(np.max(np.abs(y)))
    if peak == 0.0:
        return spectrum
    level = peak / drive
    return scipy.fft.rfft(level * np.tanh(y / level))


def with_echo(row: np.ndarray, fs_hz: float, delay_s: float, gain: float) -> np.ndarray:
    """`row` (volts) plus `gain` times itself `delay_s` later: a second path from a reflector
    beside the microphone, for everything it hears. The delay is exact (a linear phase on a
    zero-padded FFT), so a fraction of a sample stays a fraction of a sample."""
    n = row.shape[0]
    n_fft = fft_length(n + int(np.ceil(delay_s * fs_hz)) + 16)
    freqs = np.fft.rfftfreq(n_fft, 1.0 / fs_hz)
    spectrum = scipy.fft.rfft(row, n=n_fft) * (1.0 + gain * np.exp(-2j * np.pi * freqs * delay_s))
    return scipy.fft.irfft(spectrum, n=n_fft)[:n]


def overdrive_gain(peak_v: float, fraction: float, range_v: float) -> float:
    """The input stage's gain that brings a burst of peak `peak_v` to the channel's full
    scale (`range_v`) at `fraction` of its peak: everything above that clips."""
    return range_v / (fraction * peak_v)
