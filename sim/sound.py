"""Sound in the simulated world: MLS bursts, the speaker's response, propagation through air.

Propagation is exact for band-limited signals: each path applies its delay r / c (plus the
board latency) as a linear phase in the frequency domain, on a zero-padded FFT long enough that
nothing wraps around, and its 1 / r spreading as a gain. The speaker's response (a band-pass,
300 Hz - 20 kHz by default) band-limits every signal well below the Nyquist frequency, so the
fractional delays carry no interpolation error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.signal

from kernel.stimulus import mls_burst

__all__ = ["SpeakerResponse", "creeping_path_length", "fft_length", "mls_burst", "propagate"]


@dataclass(frozen=True)
class SpeakerResponse:
    """A speaker modelled as a Butterworth band-pass (its acoustic output per volt of drive).

    Attributes:
        low_hz, high_hz: the -3 dB band edges.
        order: the Butterworth order of each edge.
    """

    low_hz: float = 300.0
    high_hz: float = 20_000.0
    order: int = 2

    def frequency_response(self, freqs_hz: np.ndarray, fs_hz: float) -> np.ndarray:
        """Complex response at `freqs_hz` for a system sampled at `fs_hz`."""
        sos = scipy.signal.butter(self.order, [self.low_hz, self.high_hz], btype="bandpass",
                                  fs=fs_hz, output="sos")
        _, h = scipy.signal.sosfreqz(sos, worN=freqs_hz, fs=fs_hz)
        return h


def fft_length(n: int) -> int:
    """A fast FFT length of at least n samples."""
    return scipy.fft.next_fast_len(int(n), real=True)


def propagate(
    drive_spectrum: np.ndarray,
    n_fft: int,
    fs_hz: float,
    delays_s: np.ndarray,
    gains: np.ndarray,
    n_samples: int,
) -> np.ndarray:
    """Signals (n_paths, n_samples) arriving along each path.

    Args:
        drive_spectrum: rfft (length n_fft // 2 + 1) of the acoustic signal leaving the source
            (drive voltage times speaker response), zero-padded to n_fft samples.
        n_fft: the FFT length; must exceed n_samples plus the largest delay (no wrap-around).
        fs_hz: sample rate.
        delays_s: (n_paths,) delay of each path in seconds (any non-negative real value).
        gains: (n_paths,) amplitude factor of each path (spreading times sensitivity).
        n_samples: how many samples to return.
    """
    delays_s = np.asarray(delays_s, dtype=np.float64)
    if np.any(delays_s < 0) or n_samples + np.max(delays_s, initial=0) * fs_hz >= n_fft:
        raise ValueError("path delays must be >= 0 and shorter than the FFT padding")
    freqs = np.fft.rfftfreq(n_fft, 1.0 / fs_hz)
    phase = np.exp(-2j * np.pi * np.outer(delays_s, freqs))
    spectra = phase * (np.asarray(gains, dtype=np.float64)[:, None] * drive_spectrum[None, :])
    return scipy.fft.irfft(spectra, n=n_fft, axis=1, workers=-1)[:, :n_samples]


def creeping_path_length(source_m: np.ndarray, mics_m: np.ndarray, centre_m: np.ndarray,
                         radius_m: float) -> np.ndarray:
    """Path length (n_mics,) from a source to microphones on a rigid sphere.

    A microphone in the sphere's shadow is reached around the surface: the tangent from the
    source plus the arc from the tangent point (the creeping-wave path). Microphones in direct
    view get the straight distance.
    """
    s = source_m - centre_m
    d = float(np.linalg.norm(s))
    m = mics_m - centre_m
    direct = np.linalg.norm(mics_m - source_m, axis=1)
    if d <= radius_m:
        return direct
    cos_gamma = (m @ s) / (np.linalg.norm(m, axis=1) * d)
    gamma = np.arccos(np.clip(cos_gamma, -1.0, 1.0))
    beta = np.arccos(radius_m / d)
    around = np.sqrt(d**2 - radius_m**2) + radius_m * (gamma - beta)
    return np.where(gamma > beta, around, direct)
