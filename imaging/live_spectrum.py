"""The spectrum of the array beside the live map: what there is to hear, band by band.

`MeanSpectrum` keeps the latest window of the microphones' samples and gives, per third-octave
band (the bands a live view can choose, `octave_band_centres`, base 2), the microphones' mean
band power in dB: Welch power spectral densities of every microphone (SciPy's `welch`, Hann
blocks of the imager's length, half overlap), averaged over the microphones, integrated over
each band's bins. The level is 10 log10 of that power re 1 unit^2 of the samples (volts, or
pascals when the stream is calibrated): a level to compare bands and frames, not a sound
pressure level.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import welch

from .csm import band_edges, octave_band_centres

LOWEST_BAND_HZ = 100.0
HIGHEST_BAND_HZ = 20_000.0
"""The spectrum's band centres lie between these (and below the Nyquist frequency)."""
FLOOR_DB = -300.0
"""The level of a band without power (silence), instead of minus infinity."""


class MeanSpectrum:
    """Third-octave band levels of the microphones' mean over the latest `window_samples`
    (module docstring).

    Args:
        n_channels: M, columns of every chunk.
        sample_rate_hz: of the stream.
        window_samples: samples the levels are computed over (the map's window).
        block_size: Welch block length, samples (at most the window).
    """

    def __init__(self, n_channels: int, sample_rate_hz: float, window_samples: int,
                 block_size: int) -> None:
        self.sample_rate_hz = float(sample_rate_hz)
        self.block_size = min(int(block_size), int(window_samples))
        top = min(HIGHEST_BAND_HZ, sample_rate_hz / 2 / 2 ** (1 / 6))  # the band below Nyquist
        self.centres_hz = octave_band_centres(LOWEST_BAND_HZ, top, 3)
        self._edges = np.array([band_edges(c, 3) for c in self.centres_hz])  # (B, 2)
        self._ring = np.zeros((int(window_samples), int(n_channels)))
        self._filled = 0
        self._next = 0  # ring row of the next sample

    def restart(self) -> None:
        """Forget the samples (the stream goes on after a gap)."""
        self._filled = self._next = 0

    def push(self, samples: np.ndarray) -> None:
        """Append a chunk (n, M) of samples."""
        x = np.asarray(samples, dtype=np.float64)
        n = self._ring.shape[0]
        x = x[-n:]
        rows = (self._next + np.arange(x.shape[0])) % n
        self._ring[rows] = x
        self._next = int((self._next + x.shape[0]) % n)
        self._filled = min(n, self._filled + x.shape[0])

    @property
    def ready(self) -> bool:
        """True once a whole window has arrived."""
        return self._filled == self._ring.shape[0]

    def levels_db(self) -> np.ndarray:
        """(B,) the band levels of `centres_hz`, dB re 1 unit^2 (FLOOR_DB for a band without
        power or without a DFT bin; every band before any sample)."""
        if self._filled == 0:
            return np.full(self.centres_hz.shape, FLOOR_DB)
        window = np.roll(self._ring, -self._next, axis=0)[-self._filled:]
        freqs, psd = welch(window, self.sample_rate_hz, nperseg=min(self.block_size,
                                                                    window.shape[0]), axis=0)
        mean = psd.mean(axis=1)
        df = freqs[1] - freqs[0]
        inside = (freqs[None, :] >= self._edges[:, :1]) & (freqs[None, :] < self._edges[:, 1:])
        power = (inside * mean[None, :]).sum(axis=1) * df
        with np.errstate(divide="ignore"):
            return np.maximum(10.0 * np.log10(power), FLOOR_DB)
