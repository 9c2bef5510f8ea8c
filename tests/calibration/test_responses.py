"""calibration.acoustic.responses on synthetic impulses: the constant-Q gate and the dispersion's
bands."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from calibration.acoustic import responses
from calibration.acoustic.responses import (
    THIRD_OCTAVE_CENTRES_HZ,
    Flights,
    dispersion_centres_hz,
    estimate_responses,
)
from calibration.acoustic.times_of_flight import SessionTofs

FS = 96_000.0
STEP = 2  # full-rate samples between the impulses' values
HALF = 48  # lags either side of the arrival: 1 ms


def _pulse(t_s: np.ndarray) -> np.ndarray:
    """A band-limited pulse (300 Hz - 20 kHz, Hann-weighted) centred at t = 0."""
    f = np.arange(300.0, 20_000.0, 25.0)
    weight = np.hanning(f.size + 2)[1:-1]
    return np.cos(2 * np.pi * np.outer(t_s, f)) @ weight


def _responses_with_a_reflection(delay_s: float) -> np.ndarray:
    """Phase (rad) per band of microphone 0, which alone hears a reflection half as strong
    as the direct sound `delay_s` behind it, relative to 7 microphones that do not."""
    n_mic, n_spk = 8, 6
    t = STEP * np.arange(-HALF, HALF + 1) / FS
    impulses = np.tile(_pulse(t), (1, n_spk, n_mic, 1))
    impulses[:, :, 0] += 0.5 * _pulse(t - delay_s)
    shape = (1, n_spk, n_mic)
    tofs = SessionTofs(
        tof_s=np.zeros(shape), std_s=np.full(shape, 1e-8), snr_db=np.full(shape, 40.0),
        peak_to_sidelobe_db=np.full(shape, 20.0), reference_tof_s=np.zeros((1, n_spk)),
        reference_std_s=np.full((1, n_spk), 1e-8), impulses=impulses.astype(np.float32),
        impulse_first_lag=np.full(shape, -HALF * STEP), impulse_step=STEP,
        echo_energy=np.ones(shape), lead_energy=np.ones(shape),
        rail_samples=np.zeros(shape), dropout_share=np.zeros(shape), polarity=np.ones(n_mic))
    flights = Flights(("pose/0000",), np.zeros(shape), np.full(shape, 0.002), np.zeros(shape))
    responses = estimate_responses(tofs, [0], flights, FS, np.full(n_spk, 0.002), 343.0)
    return responses.phase_rad[0] - responses.phase_rad[1]


def test_a_reflection_stays_out_of_the_bands_whose_gate_it_misses(monkeypatch) -> None:
    """0.6 ms behind the direct sound (a table or a stand near the array): the bands from
    8 kHz up, whose gates (5 periods of the centre) end before it, see none of it. One 1 ms
    gate for every band, as before, let it turn their phase by up to a tenth of a radian."""
    high = THIRD_OCTAVE_CENTRES_HZ >= 7_900.0
    gated = _responses_with_a_reflection(0.6e-3)
    assert np.max(np.abs(gated[high])) < 0.01
    assert np.max(np.abs(gated[~high])) > 0.1  # below, the gate is too long to exclude it
    monkeypatch.setattr(responses, "GATE_CYCLES", np.inf)  # every band gated at 1 ms
    assert np.max(np.abs(_responses_with_a_reflection(0.6e-3)[high])) > 0.05


def test_the_dispersion_bands_reach_the_correlations_top() -> None:
    half = 10.0 ** 0.05
    centres = dispersion_centres_hz(20_000.0)
    assert np.all(centres[:-1] == THIRD_OCTAVE_CENTRES_HZ)
    assert centres[-1] * half == pytest.approx(20_000.0)
    for top in (8_000.0, 14_300.0, 16_000.0, 17_000.0):
        centres = dispersion_centres_hz(top)
        assert np.all(centres * half <= top * (1 + 1e-9))
        assert np.all(np.diff(centres) > 0)


def test_a_microphone_without_a_measurement_has_no_response_and_no_warning() -> None:
    """A dead microphone (no time of flight in any burst) and a speaker that did not play at
    one pose: NaN responses for that microphone alone, the others' finite, and none of
    numpy's empty-slice warnings on the user's stderr (the grid of issue 33 printed them)."""
    n_mic, n_spk, n_pose = 6, 4, 2
    rng = np.random.default_rng(3)
    t = STEP * np.arange(-HALF, HALF + 1) / FS
    impulses = _pulse(t) * rng.uniform(0.5, 2.0, (n_pose, n_spk, n_mic, 1))
    shape = (n_pose, n_spk, n_mic)

    def responses_with(tof_s: np.ndarray) -> responses.MicrophoneResponses:
        tofs = SessionTofs(
            tof_s=tof_s, std_s=np.full(shape, 1e-8), snr_db=np.full(shape, 40.0),
            peak_to_sidelobe_db=np.full(shape, 20.0), reference_tof_s=np.zeros(shape[:2]),
            reference_std_s=np.full(shape[:2], 1e-8), impulses=impulses.astype(np.float32),
            impulse_first_lag=np.full(shape, -HALF * STEP), impulse_step=STEP,
            echo_energy=np.ones(shape), lead_energy=np.ones(shape),
            rail_samples=np.zeros(shape), dropout_share=np.zeros(shape),
            polarity=np.ones(n_mic))
        flights = Flights(("pose/0000", "pose/0001"), np.zeros(shape), np.full(shape, 0.5),
                          np.zeros(shape))
        return estimate_responses(tofs, [0, 1], flights, FS, np.full(n_spk, 0.002), 343.0)

    clean = responses_with(np.zeros(shape))
    tof = np.zeros(shape)
    tof[:, :, 2] = np.nan  # the dead microphone
    tof[1, 3] = np.nan  # the speaker silent at the second pose
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mistaken = responses_with(tof)
    for values in (mistaken.gain, mistaken.phase_rad, mistaken.gain_std, mistaken.phase_std_rad):
        assert np.all(np.isnan(values[2]))
        assert np.all(np.isfinite(np.delete(values, 2, axis=0)))
    assert mistaken.n_sources == n_pose * n_spk - 1 and clean.n_sources == n_pose * n_spk
