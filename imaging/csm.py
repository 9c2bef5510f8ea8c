"""Cross-spectral matrices (CSM) by Welch averaging, for the frequency bins asked for only.

Definition and scaling (one-sided power per bin, units of the input squared, e.g. V^2 or Pa^2):

    X_b[f, m] = sum_n w[n] x_m[b*H + n] exp(-2 pi i f n / N)          (block b, hop H)
    C[f]      = 2 / (N * sum(w^2) * K) * sum_{b<K} X_b[f] X_b[f]^H      (C_mn = E[p_m p_n*])

with N the block length and K the number of whole blocks (a trailing partial block is
dropped). A delay tau of channel m appears as exp(-i omega tau) in X_b[f, m]. For white noise of
variance s^2 every bin holds 2 s^2 / N, so the bins of 0 < f < fs/2 sum to s^2; the one-sided
factor 2 is not applied at DC and Nyquist, which have no negative-frequency twin.

Differences from Acoular's `PowerSpectra` (acoular 26.8), all deliberate:
- K is the true number of averaged blocks. Acoular divides by overlap*Ns/N - overlap + 1, a
  float that exceeds the true count when Ns is not a multiple of the hop (92.75 for 92 blocks
  of 2 s at 96 kS/s: its CSM is 0.035 dB low); `acoular_block_count` gives its value.
- DC and Nyquist are not doubled (Acoular doubles them).
- Only the requested bins are computed: a windowed DFT restricted to those bins, evaluated as
  one real matrix product per block (BLAS) for a few bins, by FFT for more, and a CSM only
  for those bins instead of all N/2+1.
The window is symmetric by default, like Acoular's `np.hanning`, so the two agree bin for bin.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.signal
from numpy.lib.stride_tricks import sliding_window_view
from scipy import fft as sfft

from calibration.errors import CalibrationInputError

DFT_MAX_BINS = 80
"""Up to this many bins a direct DFT (a matrix product, N x 2F per block, at BLAS speed) is
cheaper than an FFT of every block; beyond, the FFT (measured for 72 channels of 2 s at
96 kS/s, 4096-sample blocks: 20 bins 0.046 s against 0.21 s, 100 bins 0.17 s against 0.16 s).
"""


@dataclass(frozen=True)
class WelchOptions:
    """How the recording is cut into blocks.

    Attributes:
        block_size: samples per block N (the paper: 4096).
        overlap: fraction of a block shared with the next, 0 <= overlap < 1 (the paper: 0.5).
        window: a window name scipy.signal.get_window knows ("hann", "hamming", "boxcar", ...).
        periodic: False for the symmetric window (np.hanning, Acoular), True for the periodic
            (DFT-even) one.
    """

    block_size: int = 4096
    overlap: float = 0.5
    window: str = "hann"
    periodic: bool = False

    def __post_init__(self) -> None:
        if self.block_size < 2:
            raise CalibrationInputError(f"block size {self.block_size} must be at least 2 samples")
        if not 0.0 <= self.overlap < 1.0:
            raise CalibrationInputError(f"overlap {self.overlap} must be in [0, 1)")

    @property
    def hop(self) -> int:
        """Samples between the starts of consecutive blocks."""
        return max(1, round(self.block_size * (1.0 - self.overlap)))

    def window_values(self) -> np.ndarray:
        return scipy.signal.get_window(self.window, self.block_size, fftbins=self.periodic)

    def n_blocks(self, n_samples: int) -> int:
        """Number of whole blocks in a recording of n_samples."""
        if n_samples < self.block_size:
            return 0
        return 1 + (n_samples - self.block_size) // self.hop


@dataclass(frozen=True)
class CrossSpectra:
    """Cross-spectral matrices at a set of frequencies.

    Attributes:
        freqs_hz: (F,) frequency of each matrix (a bin, or a band centre after `band_sum`).
        csm: (F, M, M) complex128 Hermitian matrices, C_mn = E[p_m p_n*], power per bin.
        n_blocks: blocks averaged.
        sample_rate_hz: of the recording.
        options: the Welch options used.
        bins: (F,) DFT bin index of each matrix, or -1 for band sums.
    """

    freqs_hz: np.ndarray
    csm: np.ndarray
    n_blocks: int
    sample_rate_hz: float
    options: WelchOptions
    bins: np.ndarray

    @property
    def n_channels(self) -> int:
        return int(self.csm.shape[1])

    def band_sum(self, centre_hz: float, fraction: int) -> CrossSpectra:
        """One matrix: the sum over the bins of the 1/fraction-octave band around centre_hz,
        labelled with the band centre (the paper's band CSM, section VI)."""
        lo, hi = band_edges(centre_hz, fraction)
        inside = (self.freqs_hz >= lo) & (self.freqs_hz < hi) & (self.bins >= 0)
        if not np.any(inside):
            raise ValueError(f"no computed bin lies in the band {lo:.1f}-{hi:.1f} Hz; compute "
                             "the CSM for the bins of `band_bins` first")
        return replace(self, freqs_hz=np.array([float(centre_hz)]),
                       csm=self.csm[inside].sum(axis=0, keepdims=True), bins=np.array([-1]))

    def select(self, lo_hz: float, hi_hz: float) -> CrossSpectra:
        """The matrices with lo_hz <= f < hi_hz."""
        inside = (self.freqs_hz >= lo_hz) & (self.freqs_hz < hi_hz)
        if not np.any(inside):
            raise CalibrationInputError(
                f"no frequency of these spectra lies in {lo_hz:.1f}-{hi_hz:.1f} Hz")
        return replace(self, freqs_hz=self.freqs_hz[inside], csm=self.csm[inside],
                       bins=self.bins[inside])


def band_edges(centre_hz: float, fraction: int) -> tuple[float, float]:
    """Edges (lo, hi) of the 1/fraction-octave band around centre_hz: centre * 2**(-+1/(2 n))."""
    if centre_hz <= 0 or fraction < 1:
        raise CalibrationInputError(
            f"a band needs centre > 0 Hz and fraction >= 1, got {centre_hz}, "
            f"{fraction}")
    half = 2.0 ** (1.0 / (2 * fraction))
    return centre_hz / half, centre_hz * half


def band_bins(centre_hz: float, fraction: int, block_size: int, sample_rate_hz: float
              ) -> np.ndarray:
    """DFT bin indices k with lo <= k fs / N < hi for the 1/fraction-octave band (Acoular's
    `synthetic` convention: 20 bins, 7781-8227 Hz, for 8 kHz, 1/12 octave, N = 4096, 96 kS/s).
    """
    lo, hi = band_edges(centre_hz, fraction)
    nyquist = sample_rate_hz / 2
    if hi > nyquist:
        raise CalibrationInputError(
            f"the band {lo:.0f}-{hi:.0f} Hz reaches above the Nyquist frequency "
            f"{nyquist:.0f} Hz")
    df = sample_rate_hz / block_size
    bins = np.arange(int(np.ceil(lo / df)), int(np.ceil(hi / df)))
    bins = bins[(bins * df >= lo) & (bins * df < hi)]
    if bins.size == 0:
        raise CalibrationInputError(
            f"the band {lo:.1f}-{hi:.1f} Hz holds no bin of a {block_size}-point "
            f"DFT at {sample_rate_hz:g} Hz (bin spacing {df:.1f} Hz); use longer "
            "blocks or a wider band")
    return bins


def octave_band_centres(lo_hz: float, hi_hz: float, fraction: int) -> np.ndarray:
    """Base-2 band centres 1000 * 2**(k / fraction) Hz that lie in [lo_hz, hi_hz]."""
    k = np.arange(np.ceil(fraction * np.log2(lo_hz / 1000.0) - 1e-9),
                  np.floor(fraction * np.log2(hi_hz / 1000.0) + 1e-9) + 1)
    centres = 1000.0 * 2.0 ** (k / fraction)
    if centres.size == 0:
        raise CalibrationInputError(
            f"no 1/{fraction}-octave band centre lies in {lo_hz}-{hi_hz} Hz")
    return centres


def acoular_block_count(n_samples: int, options: WelchOptions) -> float:
    """The block count Acoular normalises by: overlap*Ns/N - overlap + 1 with overlap the
    inverse of (1 - overlap fraction), a float (see the module docstring)."""
    factor = 1.0 / (1.0 - options.overlap)
    return factor * n_samples / options.block_size - factor + 1


def cross_spectra(signals: np.ndarray, sample_rate_hz: float, bins: Sequence[int] | np.ndarray,
                  options: WelchOptions | None = None, blocks_per_batch: int = 16
                  ) -> CrossSpectra:
    """Welch CSM of a multichannel recording at the DFT bins `bins` only.

    Args:
        signals: (n_samples, M) real samples, one column per channel.
        sample_rate_hz: sample rate.
        bins: DFT bin indices 0 <= k <= N/2 (see `band_bins`).
        options: block length, overlap and window.
        blocks_per_batch: blocks transformed per matrix product (bounds memory).

    Returns:
        CrossSpectra with freqs_hz = bins * fs / N, scaled as in the module docstring.
    """
    options = options or WelchOptions()
    x = np.asarray(signals, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] < 1:
        raise ValueError(f"signals must be (n_samples, n_channels), got shape {x.shape}")
    n = options.block_size
    bins = np.asarray(bins, dtype=np.int64).ravel()
    if bins.size == 0:
        raise ValueError("no frequency bin requested")
    if bins.min() < 0 or bins.max() > n // 2:
        raise ValueError(f"bins must lie in 0..{n // 2} (Nyquist) for {n}-sample blocks, got "
                         f"{bins.min()}..{bins.max()}")
    n_blocks = options.n_blocks(x.shape[0])
    if n_blocks == 0:
        raise CalibrationInputError(
            f"the recording has {x.shape[0]} samples, fewer than one block of {n}")
    x = np.ascontiguousarray(x)
    w = options.window_values()
    frames = sliding_window_view(x, n, axis=0)[:: options.hop][:n_blocks]  # (K, M, N) view
    if bins.size > DFT_MAX_BINS:
        spectra = _fft_spectra(frames, w, bins, blocks_per_batch)
    else:
        spectra = _dft_spectra(frames, w, bins, blocks_per_batch)
    csm = spectra @ spectra.conj().transpose(0, 2, 1)
    one_sided = np.where((bins == 0) | (2 * bins == n), 1.0, 2.0)
    csm *= (one_sided / (n * np.dot(w, w) * n_blocks))[:, None, None]
    return CrossSpectra(freqs_hz=bins * (sample_rate_hz / n), csm=csm, n_blocks=n_blocks,
                        sample_rate_hz=float(sample_rate_hz), options=options, bins=bins)


def _dft_spectra(frames: np.ndarray, window: np.ndarray, bins: np.ndarray,
                 blocks_per_batch: int) -> np.ndarray:
    """Windowed DFT (F, M, K) of the blocks (K, M, N) at `bins` only: one real matrix product
    per batch of blocks with a (N, 2F) kernel of windowed cosines and sines."""
    n_blocks, m, n = frames.shape
    angle = 2.0 * np.pi * np.outer(np.arange(n), bins) / n
    kernel = np.concatenate([window[:, None] * np.cos(angle), -window[:, None] * np.sin(angle)],
                            axis=1)
    spectra = np.empty((bins.size, m, n_blocks), dtype=np.complex128)
    for start in range(0, n_blocks, blocks_per_batch):
        part = frames[start: start + blocks_per_batch] @ kernel  # (b, M, 2F)
        block = part[..., :bins.size] + 1j * part[..., bins.size:]
        spectra[:, :, start: start + part.shape[0]] = block.transpose(2, 1, 0)
    return spectra


def _fft_spectra(frames: np.ndarray, window: np.ndarray, bins: np.ndarray,
                 blocks_per_batch: int) -> np.ndarray:
    """The same as `_dft_spectra` through real FFTs of whole blocks (cheaper beyond
    `DFT_MAX_BINS` bins)."""
    n_blocks, m, _ = frames.shape
    spectra = np.empty((bins.size, m, n_blocks), dtype=np.complex128)
    for start in range(0, n_blocks, blocks_per_batch):
        part = sfft.rfft(frames[start: start + blocks_per_batch] * window, axis=-1,
                         workers=-1)[..., bins]  # (b, M, F)
        spectra[:, :, start: start + part.shape[0]] = part.transpose(2, 1, 0)
    return spectra


def remove_diagonal(csm: np.ndarray) -> np.ndarray:
    """A copy of (..., M, M) matrices with their diagonals set to 0 (the autospectra, which
    carry each microphone's own noise)."""
    out = np.array(csm, copy=True)
    idx = np.arange(out.shape[-1])
    out[..., idx, idx] = 0.0
    return out
