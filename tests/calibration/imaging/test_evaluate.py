"""Localization evaluation and the two commands on a small simulated session."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.commands import evaluate_imaging, image, simulate
from acquisition.errors import UserError
from acquisition.session import SessionReader
from calibration.imaging import load_geometry
from calibration.imaging.evaluate import ImagingSettings, evaluate_session


def run_command(module, argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    module.register(parser.add_subparsers())
    args = parser.parse_args([module.__name__.rsplit(".", 1)[1].replace("_", "-"), *argv])
    return args.run(args)


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("imaging") / "s"
    assert run_command(simulate, ["--out", str(out), "--poses", "1", "--mls-order", "13",
                                  "--seed", "5", "--quiet"]) == 0
    return out


def test_evaluation_locates_every_speaker(session: Path) -> None:
    settings = ImagingSettings(band_lo_hz=7000.0, band_hi_hz=9000.0)
    result = evaluate_session(SessionReader(session), load_geometry(session / "truth.json"),
                              settings)
    assert {(r.pose, r.speaker) for r in result.rows} == {(0, k) for k in range(6)}
    assert len(result.by_band()) == 5  # 7127 .. 8980 Hz
    overall = result.overall()
    assert overall.mean_m < 0.002 and overall.p95_m < 0.004  # sub-grid, 6 mm grid
    assert overall.mean_node_m < 0.006
    assert json.loads(json.dumps(result.to_json()))["overall"]["count"] == 30


def test_image_command_writes_both_maps(session: Path, capsys: pytest.CaptureFixture) -> None:
    out = session.parent / "map.png"
    assert run_command(image, [str(session), "--geometry", str(session / "truth.json"),
                               "--pose", "0", "--speaker", "4", "--band", "8000",
                               "--spacing", "0.004", "--out", str(out)]) == 0
    picture = cv2.imread(str(out))
    assert picture.shape == (960, 2 * 1280, 3)
    error_mm = float(capsys.readouterr().out.split("CLEAN-SC peak ")[1].split(" mm")[0])
    assert error_mm < 4.0


def test_evaluate_imaging_command_reports_and_writes_json(session: Path,
                                                          capsys: pytest.CaptureFixture) -> None:
    report = session.parent / "eval.json"
    assert run_command(evaluate_imaging, [
        str(session), "--geometry", str(session / "truth.json"), "--band-lo", "10000",
        "--band-hi", "10500", "--json", str(report), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "all" in printed and "10079 Hz" in printed
    assert json.loads(report.read_text())["overall"]["count"] == 6


def test_commands_report_bad_input_plainly(session: Path, tmp_path: Path) -> None:
    truth = json.loads((session / "truth.json").read_text())
    del truth["poses"]
    no_poses = tmp_path / "result.json"
    no_poses.write_text(json.dumps(truth))
    with pytest.raises(UserError, match="rig pose"):
        run_command(image, [str(session), "--geometry", str(no_poses), "--pose", "0",
                            "--speaker", "0", "--band", "8000", "--out", str(tmp_path / "x.png")])
    with pytest.raises(UserError, match="Nyquist"):
        run_command(image, [str(session), "--geometry", str(session / "truth.json"), "--pose",
                            "0", "--speaker", "0", "--band", "47000", "--out",
                            str(tmp_path / "x.png")])
    with pytest.raises(UserError, match="band centre"):
        run_command(evaluate_imaging, [str(session), "--geometry", str(session / "truth.json"),
                                       "--band-lo", "5010", "--band-hi", "5020", "--quiet"])
    assert not list(tmp_path.glob("*.png"))
    np.testing.assert_equal(len(load_geometry(session / "truth.json").mic_ids), 72)


def test_geometry_reads_board_latencies_per_microphone(session: Path) -> None:
    truth = json.loads((session / "truth.json").read_text())
    geometry = load_geometry(session / "truth.json")
    for mic, latency in zip(truth["microphones"], geometry.mic_latencies_s, strict=True):
        assert latency == truth["board_latencies_s"][mic["board"]]


def test_poses_in_worker_processes_give_the_same_localizations(tmp_path: Path) -> None:
    out = tmp_path / "s"
    assert run_command(simulate, ["--out", str(out), "--poses", "2", "--mls-order", "11",
                                  "--seed", "8", "--quiet"]) == 0
    settings = ImagingSettings(band_lo_hz=9000.0, band_hi_hz=10000.0)
    geometry = load_geometry(out / "truth.json")
    seen: list[tuple[int, int]] = []
    alone = evaluate_session(SessionReader(out), geometry, settings)
    shared = evaluate_session(SessionReader(out), geometry, settings,
                              lambda done, total: seen.append((done, total)), workers=2)
    assert shared.rows == alone.rows and len(alone.rows) == 2 * 6  # one band: 9514 Hz
    assert seen == [(6, 12), (12, 12)]  # after each pose
