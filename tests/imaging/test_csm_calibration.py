"""Channel responses, the CSM correction and Dougherty's eigenvalue calibration on exact
cross-spectral matrices (the session-level effect is in test_csm_session.py)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from calibration.errors import CalibrationInputError
from imaging import SteeringModel, WelchOptions
from imaging.csm import CrossSpectra
from imaging.csm_calibration import (
    ChannelResponses,
    apply_responses,
    correct_csm,
    eigen_calibration,
    responses_from_document,
    simulated_phase_error,
)
from imaging.steering import Formulation
from sim.arrays import array_layout

from .helpers import C, point_source_csm

MICS = array_layout("sphere72").mic_positions_m
SOURCE = np.array([0.05, -0.03, 0.8])
FREQS = np.arange(340, 352) * (96_000 / 4096)  # the 12 bins of 8 kHz's band, roughly


def spectra_of(csm: np.ndarray, freqs: np.ndarray = FREQS) -> CrossSpectra:
    return CrossSpectra(freqs_hz=freqs, csm=csm, n_blocks=1, sample_rate_hz=96_000.0,
                        options=WelchOptions(), bins=np.round(freqs * 4096 / 96_000).astype(int))


def random_responses(rng: np.random.Generator, freqs: np.ndarray) -> np.ndarray:
    """(F, M) responses: 1 dB gain spread, 3 degrees of phase, a slow drift with frequency."""
    gain = 10 ** (rng.normal(0, 1.0, MICS.shape[0]) / 20)
    phase = np.radians(rng.normal(0, 3.0, MICS.shape[0]))
    drift = np.radians(1.0) * (freqs[:, None] - freqs[0]) / (freqs[-1] - freqs[0])
    return gain * np.exp(1j * (phase + drift * rng.normal(0, 1, MICS.shape[0])))


def test_correction_undoes_the_responses_with_the_agreed_sign() -> None:
    rng = np.random.default_rng(0)
    h = random_responses(rng, FREQS)
    ideal = np.array([point_source_csm(MICS, SOURCE, 1.0, f) for f in FREQS])
    recorded = apply_responses(spectra_of(ideal), ChannelResponses(FREQS, h, "test"))
    # p_m = H_m p_m(ideal): C_mn = H_m conj(H_n) C_mn(ideal)
    assert recorded.csm[3, 5, 9] == pytest.approx(h[3, 5] * np.conj(h[3, 9]) * ideal[3, 5, 9])
    back = correct_csm(recorded, ChannelResponses(FREQS, h, "test"))
    np.testing.assert_allclose(back.csm, ideal, rtol=1e-12, atol=1e-12 * np.abs(ideal).max())


def test_responses_interpolate_gain_and_unwrapped_phase() -> None:
    freqs = np.array([1000.0, 2000.0])
    h = np.array([[2.0 * np.exp(1j * np.radians(170.0))], [4.0 * np.exp(1j * np.radians(-170.0))]])
    mid = ChannelResponses(freqs, h, "test").at(np.array([500.0, 1500.0, 9000.0]))
    assert abs(mid[1, 0]) == pytest.approx(3.0)
    assert np.degrees(np.angle(mid[1, 0])) == pytest.approx(180.0, abs=1e-9) or np.degrees(
        np.angle(mid[1, 0])) == pytest.approx(-180.0, abs=1e-9)  # through 180, not through 0
    assert mid[0, 0] == pytest.approx(h[0, 0]) and mid[2, 0] == pytest.approx(h[1, 0])


def _transfer(freqs: np.ndarray) -> np.ndarray:
    model = SteeringModel(SOURCE[None], MICS, C, Formulation.CLASSIC)
    return np.array([model.vectors(f)[0] for f in freqs]) / model.distances[0]


def test_eigenvalue_calibration_recovers_every_channel_up_to_the_gauge() -> None:
    rng = np.random.default_rng(1)
    h = random_responses(rng, FREQS)
    csm = np.array([point_source_csm(MICS, SOURCE, 1.0, f) for f in FREQS])
    csm = h[:, :, None] * csm * h.conj()[:, None, :]
    # Channel noise of very different levels (up to the signal's own), on the diagonal: the
    # plain principal eigenvector is then off by 1 % in gain, the reconstructed one by 5e-6.
    noise = rng.uniform(0.05, 1.0, MICS.shape[0]) * np.abs(csm[0]).mean()
    csm += np.eye(MICS.shape[0]) * noise
    estimate = eigen_calibration(spectra_of(csm), _transfer(FREQS), np.array([8000.0]), 12,
                                 "test")
    truth = h.mean(axis=0)  # the band's average response
    truth = truth * np.exp(-1j * np.angle(np.mean(truth / np.abs(truth))))
    truth /= np.sqrt(np.mean(np.abs(truth) ** 2))
    np.testing.assert_allclose(np.abs(estimate.responses[0]), np.abs(truth), rtol=1e-4)
    np.testing.assert_allclose(np.angle(estimate.responses[0] / truth), 0.0, atol=2e-3)
    assert np.mean(np.abs(estimate.responses[0]) ** 2) == pytest.approx(1.0)


def test_eigenvalue_calibration_refuses_two_sources() -> None:
    other = np.array([-0.2, 0.1, 0.9])
    csm = np.array([point_source_csm(MICS, np.vstack([SOURCE, other]), [1.0, 0.7], f)
                    for f in FREQS])
    with pytest.raises(CalibrationInputError, match="not dominated by one source"):
        eigen_calibration(spectra_of(csm), _transfer(FREQS), np.array([8000.0]), 12, "test")
    with pytest.raises(CalibrationInputError, match="no bin"):
        eigen_calibration(spectra_of(csm), _transfer(FREQS), np.array([12000.0]), 12, "test")


def test_simulated_phase_error_has_the_asked_spread() -> None:
    error = simulated_phase_error(2000, 2.0, seed=3)
    assert np.std(np.degrees(np.angle(error.responses))) == pytest.approx(2.0, rel=0.05)
    assert np.all(np.abs(error.responses) == pytest.approx(1.0))
    with pytest.raises(CalibrationInputError, match="0-90"):
        simulated_phase_error(3, -1.0)


def _document(**changes) -> dict:
    block = {"frequencies_hz": [1000.0, 8000.0],
             "microphones": [{"id": m, "gain": [1.0, 1.1], "phase_rad": [0.0, 0.01 * m]}
                             for m in range(3)]}
    block.update(changes)
    return {"microphone_responses": block}


def test_responses_from_a_result_document_and_its_errors() -> None:
    assert responses_from_document({}, (0, 1, 2), "result.json") is None
    read = responses_from_document(_document(), (2, 0, 1), "result.json")
    assert read is not None
    assert read.responses.shape == (2, 3)
    assert read.responses[1, 0] == pytest.approx(1.1 * np.exp(0.02j))  # in the asked order
    bad = {
        "no response for microphones [3]": _document(),
        "one value per frequency": _document(microphones=[
            {"id": 0, "gain": [1.0], "phase_rad": [0.0]}]),
        "positive and finite": _document(microphones=[
            {"id": m, "gain": [1.0, -1.0], "phase_rad": [0.0, 0.0]} for m in range(4)]),
        "strictly increasing": _document(frequencies_hz=[8000.0, 1000.0], microphones=[
            {"id": m, "gain": [1.0, 1.0], "phase_rad": [0.0, 0.0]} for m in range(4)]),
        "frequencies_hz must list": _document(frequencies_hz=[]),
        "listed twice": _document(microphones=[
            {"id": 0, "gain": [1.0, 1.0], "phase_rad": [0.0, 0.0]}] * 2),
        "microphones": {"microphone_responses": {"frequencies_hz": [1.0]}},
    }
    for message, document in bad.items():
        with pytest.raises(CalibrationInputError, match=re.escape(message)):
            responses_from_document(document, (0, 1, 2, 3), "result.json")
