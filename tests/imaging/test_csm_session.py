"""The CSM calibration on a simulated session: 2 degrees of microphone phase error degrade
CLEAN-SC's localization and the map's peak; Dougherty's eigenvalue calibration from one
recording restores both; a result's microphone_responses go through the same correction."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from acquisition.contracts.errors import UserError
from acquisition.contracts.session import SessionReader
from imaging import load_geometry
from imaging.csm_calibration import simulated_phase_error
from imaging.evaluate import ImagingSettings, channel_calibration, evaluate_session
from micam.commands import evaluate_imaging
from tests.conftest import simulated_session

from .test_evaluate import run_command

pytestmark = pytest.mark.slow  # every test here: a recorded session

SETTINGS = ImagingSettings(band_lo_hz=7000.0, band_hi_hz=11000.0)  # 8 bands
CALIBRATION = (0, 4)


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulated_session(tmp_path_factory, "csm", "--poses", "2", "--mls-order", "12",
                             "--seed", "21")


def _evaluate(session: Path, settings: ImagingSettings):
    geometry = load_geometry(session / "truth.json")
    result = evaluate_session(SessionReader(session), geometry, settings, skip={CALIBRATION})
    peaks = np.array([r.dirty_peak for r in result.rows])
    return result.overall().mean_m, peaks, result.rows


def test_eigenvalue_calibration_restores_the_map_after_a_phase_error(session: Path) -> None:
    geometry = load_geometry(session / "truth.json")
    error = simulated_phase_error(geometry.n_mics, 2.0, seed=0)
    clean_mean, clean_peaks, clean_rows = _evaluate(session, SETTINGS)
    wrong = replace(SETTINGS, simulated_error=error)
    wrong_mean, wrong_peaks, _ = _evaluate(session, wrong)
    correction = channel_calibration(SessionReader(session), geometry, *CALIBRATION, wrong)
    fixed_mean, fixed_peaks, fixed_rows = _evaluate(session, replace(wrong,
                                                                     correction=correction))
    assert [(r.pose, r.speaker, r.band_hz) for r in fixed_rows] == [
        (r.pose, r.speaker, r.band_hz) for r in clean_rows]
    # 2 degrees move the CLEAN-SC peaks by tenths of a millimetre: many times the error-free
    # sub-grid error (tens of micrometres); the calibration brings them back.
    assert wrong_mean > 4 * clean_mean
    assert fixed_mean < 1.5 * clean_mean
    # The delay-and-sum peak drops by about sigma^2 = 1.2e-3 of its power (-0.005 dB); the
    # calibration, which keeps the array's total power, evens out the simulated world's 1 dB
    # gain spread too, so the peak ends above the error-free one (about 1.3e-2 for 1 dB).
    assert np.mean(wrong_peaks / clean_peaks) == pytest.approx(1 - 1.2e-3, abs=4e-4)
    assert np.mean(fixed_peaks / clean_peaks) > 1 + 5e-3
    # It measured the phases that were put in (the gauge: their circular mean removed).
    put = np.angle(error.responses[0] * np.conj(np.mean(error.responses[0])))
    found = np.angle(correction.responses)
    assert np.sqrt(np.mean((found - put) ** 2)) < np.radians(0.3)


def test_result_responses_take_the_same_path(session: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture) -> None:
    """A result.json whose microphone_responses are exactly the simulated error: correcting
    with them gives the error-free localizations back (a sign error would double it)."""
    truth = json.loads((session / "truth.json").read_text())
    ids = sorted(m["id"] for m in truth["microphones"])
    error = simulated_phase_error(len(ids), 2.0, seed=5)
    result = dict(truth, microphone_responses={
        "frequencies_hz": [100.0, 40000.0],
        "microphones": [{"id": mic, "gain": [1.0, 1.0], "phase_rad": [float(p), float(p)]}
                        for mic, p in zip(ids, np.angle(error.responses[0]), strict=True)]})
    path = tmp_path / "result.json"
    path.write_text(json.dumps(result))
    common = [str(session), "--geometry", str(path), "--band-lo", "8000", "--band-hi", "12000",
              "--quiet", "--workers", "1"]
    outputs = {}
    for name, extra in (("clean", []), ("error", ["--mic-phase-error-deg", "2",
                                                  "--mic-phase-error-seed", "5"]),
                        ("fixed", ["--mic-phase-error-deg", "2", "--mic-phase-error-seed", "5",
                                   "--responses"])):
        out = tmp_path / f"{name}.json"
        assert run_command(evaluate_imaging, [*common, *extra, "--json", str(out)]) == 0
        outputs[name] = json.loads(out.read_text())["overall"]
    printed = capsys.readouterr().out
    assert "CSM corrected by the" in printed and "microphone_responses" in printed
    assert outputs["error"]["mean_mm"] > 3 * outputs["clean"]["mean_mm"]
    assert outputs["fixed"]["mean_mm"] == pytest.approx(outputs["clean"]["mean_mm"], rel=1e-6)
    with pytest.raises(UserError, match="no microphone_responses"):
        run_command(evaluate_imaging, [str(session), "--geometry", str(session / "truth.json"),
                                       "--responses", "--quiet"])


def test_calibration_recording_must_exist_and_is_left_out(session: Path,
                                                          tmp_path: Path) -> None:
    args = [str(session), "--geometry", str(session / "truth.json"), "--band-lo", "9000",
            "--band-hi", "10000", "--quiet", "--workers", "1"]
    with pytest.raises(UserError, match="speakers 0-5, not 9"):
        run_command(evaluate_imaging, [*args, "--csm-calibration", "0:9"])
    with pytest.raises(UserError, match="no rig pose 7"):
        run_command(evaluate_imaging, [*args, "--csm-calibration", "7:0"])
    with pytest.raises(SystemExit):  # argparse: not POSE:SPEAKER
        run_command(evaluate_imaging, [*args, "--csm-calibration", "zero"])
    out = tmp_path / "eval.json"
    assert run_command(evaluate_imaging, [*args, "--csm-calibration", "1:2", "--json",
                                          str(out)]) == 0
    document = json.loads(out.read_text())
    assert document["overall"]["count"] == 11  # 12 recordings, one 9514 Hz band, 1:2 left out
    assert "pose/0001 speaker 2" in document["settings"]["correction"]
