"""The Welch CSM against a direct computation, its scaling, bands and input checks."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import CalibrationInputError
from imaging import (
    WelchOptions,
    band_bins,
    band_edges,
    cross_spectra,
    octave_band_centres,
    remove_diagonal,
)
from imaging.csm import acoular_block_count


def direct_csm(x: np.ndarray, bins: np.ndarray, n: int, hop: int) -> np.ndarray:
    """The textbook Welch estimate with a full FFT per block and an explicit average."""
    w = np.hanning(n)
    starts = range(0, x.shape[0] - n + 1, hop)
    spectra = [np.fft.rfft(w[:, None] * x[s: s + n], axis=0)[bins] for s in starts]
    csm = np.mean([np.einsum("fm,fn->fmn", X, X.conj()) for X in spectra], axis=0)
    return csm * 2 / (n * np.sum(w**2))


@pytest.mark.parametrize("overlap", [0.5, 0.75, 0.0])
@pytest.mark.parametrize("bins", [np.array([3, 17, 64, 100]),  # a few: direct DFT
                                  np.arange(1, 128)])  # many (> DFT_MAX_BINS): FFT
def test_csm_matches_direct_computation(overlap: float, bins: np.ndarray) -> None:
    rng = np.random.default_rng(1)
    x = rng.standard_normal((5000, 5)) @ rng.standard_normal((5, 5))
    options = WelchOptions(block_size=256, overlap=overlap)
    spectra = cross_spectra(x, 1000.0, bins, options)
    expected = direct_csm(x, bins, 256, options.hop)
    assert spectra.n_blocks == 1 + (5000 - 256) // options.hop
    np.testing.assert_allclose(spectra.csm, expected, rtol=1e-12,
                               atol=1e-15 * np.abs(expected).max())
    np.testing.assert_allclose(spectra.freqs_hz, bins * 1000.0 / 256)
    # Hermitian, and the orientation C_mn = E[p_m p_n*]: a delay shows as exp(-i omega tau).
    np.testing.assert_allclose(spectra.csm, spectra.csm.conj().transpose(0, 2, 1))


def test_delay_orientation() -> None:
    fs, n, delay = 1000.0, 128, 3
    x = np.random.default_rng(2).standard_normal(4000)
    y = np.column_stack([x[delay:], x[:-delay]])  # channel 1 lags channel 0 by `delay`
    k = 10
    c = cross_spectra(y, fs, [k], WelchOptions(block_size=n)).csm[0]
    assert np.angle(c[1, 0]) == pytest.approx(-2 * np.pi * k * delay / n, abs=0.05)


def test_white_noise_bins_sum_to_the_variance() -> None:
    sigma = 0.3
    x = sigma * np.random.default_rng(3).standard_normal((200_000, 1))
    spectra = cross_spectra(x, 1.0, np.arange(1, 512), WelchOptions(block_size=1024))
    total = np.real(spectra.csm[:, 0, 0]).sum() * 512 / 511
    assert total == pytest.approx(sigma**2, rel=0.02)


def test_band_bins_follow_acoulars_convention() -> None:
    bins = band_bins(8000.0, 12, 4096, 96_000.0)
    assert bins[0] == 332 and bins[-1] == 351 and bins.size == 20
    lo, hi = band_edges(8000.0, 12)
    assert lo == pytest.approx(8000 * 2 ** (-1 / 24)) and hi == pytest.approx(8000 * 2 ** (1 / 24))


def test_band_sum_adds_the_band_bins() -> None:
    x = np.random.default_rng(4).standard_normal((20_000, 3))
    bins = band_bins(8000.0, 12, 4096, 96_000.0)
    spectra = cross_spectra(x, 96_000.0, np.arange(300, 400))
    band = spectra.band_sum(8000.0, 12)
    np.testing.assert_allclose(band.csm[0], spectra.csm[bins - 300].sum(axis=0))
    assert band.freqs_hz[0] == 8000.0


def test_octave_band_centres_cover_5_to_15_khz() -> None:
    centres = octave_band_centres(5000.0, 15000.0, 12)
    assert centres.size == 19
    np.testing.assert_allclose(np.diff(np.log2(centres)), 1 / 12)


def test_remove_diagonal_leaves_the_input_alone() -> None:
    c = np.ones((2, 3, 3), dtype=complex)
    out = remove_diagonal(c)
    assert np.all(np.diagonal(out, axis1=1, axis2=2) == 0) and np.all(c == 1)


def test_acoular_block_count_is_the_float_quirk() -> None:
    assert acoular_block_count(192_000, WelchOptions()) == pytest.approx(92.75)
    assert WelchOptions().n_blocks(192_000) == 92


@pytest.mark.parametrize(("call", "message", "error"), [
    (lambda: band_bins(45_000.0, 3, 4096, 96_000.0), "Nyquist", CalibrationInputError),
    (lambda: band_bins(100.0, 12, 256, 96_000.0), "holds no bin", CalibrationInputError),
    (lambda: cross_spectra(np.zeros((100, 2)), 1e3, [1], WelchOptions(block_size=256)),
     "fewer than one block", CalibrationInputError),
    (lambda: WelchOptions(overlap=1.0), "overlap", CalibrationInputError),
    # the calling code's mistakes, not the user's: bugs
    (lambda: cross_spectra(np.zeros((1000, 2)), 1e3, [129], WelchOptions(block_size=256)),
     "Nyquist", ValueError),
    (lambda: cross_spectra(np.zeros(1000), 1e3, [1], WelchOptions(block_size=256)),
     "n_channels", ValueError),
    (lambda: cross_spectra(np.zeros((1000, 2)), 1e3, [], WelchOptions(block_size=256)),
     "no frequency", ValueError),
])
def test_bad_input_is_refused_clearly(call, message: str, error: type[Exception]) -> None:
    with pytest.raises(error, match=message):
        call()
