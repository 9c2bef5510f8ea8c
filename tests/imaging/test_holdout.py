"""Held-out imaging: every pose imaged with a calibration that never saw its sources, beside
the in-sample evaluation; distance classes measured as `micam simulate --distance` draws."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from acquisition.contracts.errors import UserError
from calibration.errors import CalibrationInputError
from imaging import load_geometry
from imaging.evaluate import ImagingSettings
from imaging.holdout import cross_validate, fold_poses
from micam.commands import evaluate_imaging
from tests.conftest import simulated_session

from .test_evaluate import run_command

SETTINGS = ImagingSettings(band_lo_hz=9000.0, band_hi_hz=10000.0)  # one band: 9514 Hz


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four poses with the rig's pattern centre 0.7-0.9 m from camera 0."""
    return simulated_session(tmp_path_factory, "holdout", "--poses", "4", "--mls-order", "11",
                             "--distance", "0.7", "0.9", "--seed", "13")


def test_folds_deal_the_poses_and_keep_enough_to_calibrate() -> None:
    assert fold_poses([0, 1, 2, 3, 4], 2) == [[0, 2, 4], [1, 3]]
    assert fold_poses([0, 1, 2], 3) == [[0], [1], [2]]
    with pytest.raises(CalibrationInputError, match="2 poses to calibrate from"):
        fold_poses([0, 1, 2], 2)
    with pytest.raises(CalibrationInputError, match="cannot be split into 7 folds"):
        fold_poses([0, 1, 2, 3, 4, 5], 7)
    with pytest.raises(CalibrationInputError, match="at least 2"):
        fold_poses([0, 1, 2, 3], 1)


@pytest.mark.slow
def test_held_out_poses_are_imaged_with_a_calibration_that_never_saw_them(
        session: Path) -> None:
    truth = load_geometry(session / "truth.json")
    cv = cross_validate(session, 2, SETTINGS, truth=truth)
    assert cv.folds == [[0, 2], [1, 3]]
    recordings = {(p, s) for p in range(4) for s in range(6)}
    for ev in (cv.in_sample, cv.held_out):
        assert {(r.pose, r.speaker) for r in ev.rows} == recordings
        assert len(ev.rows) == 24
        # Classed by the pattern centre's distance from camera 0, inside --distance.
        assert all(0.7 - 1e-3 <= r.distance_m <= 0.9 + 1e-3 for r in ev.rows)
        assert list(ev.by_distance()) == [(0.6, 1.0)]
    inside = {(r.pose, r.speaker): r for r in cv.in_sample.rows}
    changed = [abs(r.error_m - inside[(r.pose, r.speaker)].error_m) for r in cv.held_out.rows]
    assert min(changed) > 0  # other microphone positions: every map moved
    # Held-out is what a new recording would see: no better against the truth than in-sample
    # on average, and still sub-millimetre (two poses calibrate 72 microphones to ~0.1 mm).
    held_out, in_sample = cv.held_out.overall().truth_mean_m, cv.in_sample.overall().truth_mean_m
    assert held_out is not None and in_sample is not None  # the truth is known
    assert held_out >= 0.8 * in_sample
    assert held_out < 1e-3
    assert json.loads(json.dumps(cv.to_json()))["held_out"]["overall"]["count"] == 24


@pytest.mark.slow
def test_the_command_prints_in_sample_beside_held_out(session: Path, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture) -> None:
    figure = tmp_path / "cv.png"
    assert run_command(evaluate_imaging, [
        str(session), "--folds", "2", "--band-lo", "9000", "--band-hi", "10000", "--quiet",
        "--workers", "1", "--figure", str(figure), "--json", str(tmp_path / "cv.json")]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert "in-sample" in printed[2] and "held-out (2 folds)" in printed[2]
    header = printed[3].split()
    assert header == ["n", "mean", "median", "p95", "truth"] * 2
    rows = {line.split()[0]: line.split()[1:] for line in printed[4:] if line.split()}
    assert rows["all"][0] == rows["all"][5] == "24"
    assert "0.6-1.0" in rows  # the distance class of --distance 0.7 0.9
    means = np.array([float(rows["all"][1]), float(rows["all"][6])])
    assert np.all(means > 0) and np.all(means < 1.0)  # mm
    assert figure.stat().st_size < 200_000
    document = json.loads((tmp_path / "cv.json").read_text())
    assert document["folds"] == [[0, 2], [1, 3]]
    with pytest.raises(UserError, match="with --geometry, not --folds"):
        run_command(evaluate_imaging, [str(session), "--folds", "2", "--responses"])
    with pytest.raises(UserError, match="cannot be split"):
        run_command(evaluate_imaging, [str(session), "--folds", "5", "--quiet"])
