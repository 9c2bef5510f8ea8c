"""Cross-spectral matrices over a window that slides along a stream of samples.

Samples arrive in chunks of any size (`push`); every whole Welch block (`csm.WelchOptions`:
length N, hop N (1 - overlap)) is transformed at the band's DFT bins as soon as its last sample
is in (`csm._dft_spectra`, one matrix product), and the spectra of the latest `n_blocks` blocks
are kept. `csm()` is then the Welch CSM of exactly those blocks, with the scaling of
`csm.cross_spectra` (one-sided power per bin), so a window's matrices equal those of
`cross_spectra` on the window's samples (tested). The per-block spectra are optionally
divided by each channel's calibrated response (`ChannelResponses`: the correction of
`csm_calibration.correct_csm`, applied to the spectra instead of the matrices).

Cost per block for 72 channels, N = 1024 and the ten bins of a third octave at 4 kHz: a
(72 x 1024) x (1024 x 20) product; per CSM: a (F, M, K) x (F, K, M) product. Both are far
below the beamformer's cost.
"""

from __future__ import annotations

import numpy as np

from calibration._blas import single_threaded_blas

from .csm import WelchOptions, _dft_spectra
from .csm_calibration import ChannelResponses


class SlidingCsm:
    """The Welch CSM of the latest `n_blocks` blocks of a multichannel stream, at `bins`.

    Args:
        n_channels: M, columns of every chunk.
        sample_rate_hz: of the stream.
        bins: DFT bin indices of the matrices (`csm.band_bins`).
        options: block length, overlap, window.
        n_blocks: blocks averaged per CSM (the window is N + (n_blocks - 1) hop samples).
        responses: channel responses to correct for, or None.
    """

    def __init__(self, n_channels: int, sample_rate_hz: float, bins: np.ndarray,
                 options: WelchOptions, n_blocks: int,
                 responses: ChannelResponses | None = None) -> None:
        if n_blocks < 1:
            raise ValueError(f"a sliding CSM averages at least 1 block, not {n_blocks}")
        self.bins = np.asarray(bins, dtype=np.int64).ravel()
        n = options.block_size
        if self.bins.size == 0 or self.bins.min() < 1 or self.bins.max() >= n // 2:
            raise ValueError(f"bins must lie strictly between DC and Nyquist (1..{n // 2 - 1})")
        self.options = options
        self.n_channels = int(n_channels)
        self.n_blocks = int(n_blocks)
        self.freqs_hz = self.bins * (sample_rate_hz / n)
        self._window = options.window_values()
        self._scale = 2.0 / (n * float(np.dot(self._window, self._window)))
        self._correction = None
        if responses is not None:
            if responses.n_channels != self.n_channels:
                raise ValueError(f"{responses.n_channels} channel responses for a stream of "
                                 f"{self.n_channels} channels")
            self._correction = (1.0 / responses.at(self.freqs_hz))[:, :, None]  # (F, M, 1)
        self._spectra = np.zeros((self.bins.size, self.n_channels, self.n_blocks),
                                 dtype=np.complex128)
        self._filled = 0  # blocks in the ring (up to n_blocks)
        self._next = 0  # ring slot of the next block
        self._pending = np.zeros((0, self.n_channels))  # samples not yet in a whole block
        self.samples_in = 0  # stream index one past the newest sample pushed
        self.last_block_end = 0  # stream index one past the newest transformed block

    def restart(self, at_sample: int) -> None:
        """Forget every block: the stream goes on at index `at_sample` after a gap (samples
        were lost), and no window may span the gap."""
        self._filled = 0
        self._next = 0
        self._pending = np.zeros((0, self.n_channels))
        self.samples_in = self.last_block_end = int(at_sample)

    @property
    def window_samples(self) -> int:
        """Samples covered by a full window of n_blocks blocks."""
        return self.options.block_size + (self.n_blocks - 1) * self.options.hop

    @property
    def ready(self) -> bool:
        """True once a full window of blocks has been transformed."""
        return self._filled == self.n_blocks

    def push(self, samples: np.ndarray) -> int:
        """Append a chunk (n, M) of samples; returns the number of new blocks transformed."""
        x = np.asarray(samples, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.n_channels:
            raise ValueError(f"chunks must be (n_samples, {self.n_channels}), got {x.shape}")
        self.samples_in += x.shape[0]
        data = np.concatenate([self._pending, x]) if self._pending.size else x
        n, hop = self.options.block_size, self.options.hop
        count = 0 if data.shape[0] < n else 1 + (data.shape[0] - n) // hop
        if count:
            # keep at most a ring's worth of the newest blocks
            skip = max(0, count - self.n_blocks)
            starts = hop * np.arange(skip, count)
            frames = np.stack([data[s: s + n].T for s in starts])  # (K, M, N)
            with single_threaded_blas():  # small products: see calibration._blas
                spectra = _dft_spectra(frames, self._window, self.bins, len(starts))  # (F,M,K)
            if self._correction is not None:
                spectra *= self._correction
            slots = (self._next + np.arange(spectra.shape[2])) % self.n_blocks
            self._spectra[:, :, slots] = spectra
            self._next = int((self._next + spectra.shape[2]) % self.n_blocks)
            self._filled = min(self.n_blocks, self._filled + spectra.shape[2])
            self.last_block_end = self.samples_in - (data.shape[0] - (hop * (count - 1) + n))
        keep_from = hop * count
        self._pending = data[keep_from:].copy()
        return count

    def csm(self) -> np.ndarray:
        """(F, M, M) complex128: the CSM of the blocks in the ring (all n_blocks once
        `ready`), C_mn = E[p_m p_n*], one-sided power per bin."""
        if self._filled == 0:
            raise ValueError("no whole block has arrived yet")
        s = self._spectra if self.ready else self._spectra[:, :, :self._filled]
        out = s @ s.conj().transpose(0, 2, 1)
        out *= self._scale / self._filled
        return out

    def band_csm(self) -> np.ndarray:
        """(M, M): the sum of `csm()` over the bins (the band's CSM, paper section VI)."""
        return self.csm().sum(axis=0)
