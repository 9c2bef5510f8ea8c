"""Localization evaluation and the two commands on a small simulated session."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.contracts.errors import UserError
from acquisition.contracts.session import SessionReader
from calibration.errors import CalibrationInputError
from imaging import load_geometry
from imaging.evaluate import ImagingSettings, evaluate_session
from micam.commands import evaluate_imaging, image, simulate

pytestmark = pytest.mark.slow  # every test here: a recorded session, imaged


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


def test_image_command_writes_a_small_figure(session: Path, capsys: pytest.CaptureFixture
                                            ) -> None:
    out = session.parent / "map.png"
    assert run_command(image, [str(session), "--geometry", str(session / "truth.json"),
                               "--pose", "0", "--speaker", "4", "--band", "8000",
                               "--out", str(out)]) == 0
    picture = cv2.imread(str(out))
    assert picture is not None
    assert 1000 <= picture.shape[1] <= 1100 and picture.shape[0] < 600  # a page, not 2560 px
    assert out.stat().st_size < 200_000
    printed = capsys.readouterr().out
    error_mm = float(printed.split("CLEAN-SC peak ")[1].split(" mm")[0])
    assert 0 < error_mm < 0.5  # sub-grid, printed with its significant digits (not "0.0")


def _png_pixel(fig, ax, xy: np.ndarray) -> np.ndarray:
    """Row, column of the saved PNG where data point xy of ax lands."""
    x, y = ax.transData.transform(np.atleast_2d(xy)).T
    return np.column_stack([fig.bbox.height - y, x])


def test_map_figure_marks_speakers_and_sources_at_their_pixels(session: Path,
                                                              tmp_path: Path) -> None:
    from calibration.figures.maps import PLAYING_COLOUR, map_colours
    from calibration.figures.style import save
    from imaging.figures.recording_map import recording_map

    drawn = recording_map(SessionReader(session), load_geometry(session / "truth.json"), 0, 2,
                          8000.0, ImagingSettings(bands_hz=(8000.0,)), dynamic_range_db=20.0)
    assert drawn.speaker_in_view
    fig = drawn.figure
    path = save(fig, tmp_path / "map.png")
    image = cv2.imread(str(path))
    assert image is not None
    rgb = image[..., ::-1].astype(float)
    das, clean = (next(a for a in fig.axes if a.get_gid() == f"map-{k}") for k in (0, 1))
    bar = next(a for a in fig.axes if a.get_gid() == "colour-bar")
    assert "dB" in bar.get_ylabel() and bar.get_ylim() == pytest.approx((-20.0, 0.0))
    assert das.get_aspect() == 1.0 and clean.get_aspect() == 1.0  # square image pixels
    ring = np.sqrt(60) / 2 * 150 / 72  # marker radius in pixels: s = 60 pt^2, 150 dpi
    angles = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    for ax in (das, clean):
        for k, centre in enumerate(_png_pixel(fig, ax, drawn.speakers_px)):
            colour = np.array([255.0, 255.0, 255.0]) if k != 2 else 255 * np.array(
                [int(PLAYING_COLOUR[i:i + 2], 16) / 255 for i in (1, 3, 5)])
            near = np.zeros(angles.size, dtype=bool)
            for radius in (ring - 1, ring, ring + 1):  # the ring's line is 2 px wide
                rows = np.rint(centre[0] + radius * np.sin(angles)).astype(int)
                cols = np.rint(centre[1] + radius * np.cos(angles)).astype(int)
                near |= np.linalg.norm(rgb[rows, cols] - colour, axis=1) < 60
            assert near.mean() > 0.8, (ax.get_gid(), k)  # a ring of the right colour there
    # The strongest CLEAN-SC point is drawn on the playing speaker in the map's top colour.
    top = 255 * np.array(map_colours()(1.0)[:3])
    row, col = np.rint(_png_pixel(fig, clean, drawn.speakers_px[2])[0]).astype(int)
    patch = rgb[row - 1:row + 2, col - 1:col + 2].reshape(-1, 3)
    assert np.min(np.linalg.norm(patch - top, axis=1)) < 40
    # The delay-and-sum map's brightest pixels sit on it too.
    x0, x1 = np.rint(das.get_window_extent().intervalx).astype(int)
    y1, y0 = np.rint(fig.bbox.height - das.get_window_extent().intervaly).astype(int)
    panel = rgb[y0:y1, x0:x1]
    bright = np.argwhere(np.linalg.norm(panel - top, axis=2) < 30)
    assert bright.size
    centre = _png_pixel(fig, das, drawn.speakers_px[2])[0] - [y0, x0]
    assert np.linalg.norm(bright.mean(axis=0) - centre) < 6  # figure pixels


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


def test_geometry_adds_each_microphones_own_delay(session: Path, tmp_path: Path) -> None:
    truth = json.loads((session / "truth.json").read_text())
    plain = load_geometry(session / "truth.json")
    for k, mic in enumerate(truth["microphones"]):
        mic["delay_s"] = 1e-7 * (k % 5)
    path = tmp_path / "result.json"
    path.write_text(json.dumps(truth))
    delayed = load_geometry(path)
    own = np.array([1e-7 * (m["id"] % 5) for m in sorted(truth["microphones"],
                                                         key=lambda m: m["id"])])
    np.testing.assert_allclose(delayed.mic_latencies_s - plain.mic_latencies_s, own)
    np.testing.assert_allclose(delayed.without_own_delays().mic_latencies_s,
                               plain.mic_latencies_s)
    truth["microphones"][3]["delay_s"] = float("nan")
    path.write_text(json.dumps(truth))
    with pytest.raises(CalibrationInputError, match="finite"):
        load_geometry(path)


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
