"""`micam calibrate` on simulated sessions: accuracy against the truth, the result's shape,
the baseline method, and clear errors for sessions that cannot be calibrated."""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from micam.cli import main
from calibration.pipeline import CalibrationOptions, calibrate
from calibration.result import compare_with_truth

pytestmark = pytest.mark.slow  # every test here: a recorded session, calibrated


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six poses (36 sources) of the 72-microphone sphere at 0.6-1.0 m, default noise."""
    path = tmp_path_factory.mktemp("cal") / "s"
    assert main(["simulate", "--out", str(path), "--poses", "6", "--mls-order", "12",
                 "--seed", "11", "--quiet"]) == 0
    return path


@pytest.fixture(scope="module")
def truth(session: Path) -> dict:
    return json.loads((session / "truth.json").read_text())


def test_calibration_is_accurate_against_the_truth(session: Path, truth: dict) -> None:
    run = calibrate(session)
    errors = compare_with_truth(run.result, truth)
    # 36 sources: the robust target is 2.0 mm at 24 sources and 1.0 mm at 96.
    assert errors["mean_mic_error_m"] < 1.0e-3
    assert abs(errors["speed_of_sound_error_m_s"]) < 0.1
    # Board latencies relative to each other: their common part trades off against the
    # camera's depth scale (a few microseconds here), their differences are well determined.
    true_lat = truth["board_latencies_s"]
    ref = true_lat[run.data.reference_group]
    boards = sorted(run.result.latency_s)
    diff = np.array([run.result.latency_s[b] - (true_lat[b] - ref) for b in boards])
    std = np.array([run.result.latency_std_s[b] for b in boards])
    assert np.all(np.abs(diff - np.median(diff)) < 4 * std + 0.1e-6)


def test_result_has_the_keys_of_the_truth(session: Path, truth: dict, tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    xml = tmp_path / "mics.xml"
    assert main(["calibrate", str(session), "--out", str(out), "--acoular-xml", str(xml)]) == 0
    result = json.loads(out.read_text())
    assert {"microphones", "speed_of_sound_m_s", "cameras", "poses"} <= set(result)
    ids = sorted(m["id"] for m in result["microphones"])
    assert ids == sorted(m["id"] for m in truth["microphones"])
    assert all(len(m["std_m"]) == 3 and m["std_m"][0] > 0 for m in result["microphones"])
    assert (tmp_path / "result-report" / "report.md").is_file()
    assert (tmp_path / "result-report" / "geometry.png").stat().st_size > 10_000
    points = ET.parse(xml).getroot().findall("pos")
    assert [p.get("Name") for p in points] == [f"Point {k}" for k in ids]  # one numbering
    assert all(p["step"] == f"pose/{p['index']:04d}" for p in result["poses"])
    first = min(result["microphones"], key=lambda m: m["id"])["position_m"]
    assert float(points[0].get("x", "nan")) == pytest.approx(first[0], abs=1e-6)


def test_paper_method_runs_on_the_same_data(session: Path, truth: dict) -> None:
    ours = compare_with_truth(calibrate(session).result, truth)
    paper = compare_with_truth(calibrate(session, CalibrationOptions(method="paper")).result,
                               truth)
    assert paper["mean_mic_error_m"] < 5e-3  # converges, no mirror or runaway solution
    assert ours["mean_mic_error_m"] <= paper["mean_mic_error_m"]


def test_existing_result_is_not_overwritten(session: Path, tmp_path: Path,
                                            capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "r.json"
    out.write_text("{}")
    assert main(["calibrate", str(session), "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err
    assert out.read_text() == "{}"


def test_not_a_session_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["calibrate", str(tmp_path), "--out", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "micam: error:" in err and "Traceback" not in err


def test_interrupted_session_needs_permission(session: Path, tmp_path: Path,
                                              capsys: pytest.CaptureFixture) -> None:
    copy = tmp_path / "s"
    shutil.copytree(session, copy)
    journal = copy / "journal.jsonl"
    lines = journal.read_text().splitlines(keepends=True)
    journal.write_text("".join(lines[:-1]))  # drop the stop record: an interrupted session
    assert main(["calibrate", str(copy), "--out", str(tmp_path / "r.json")]) == 2
    assert "--allow-interrupted" in capsys.readouterr().err
    run = calibrate(copy, CalibrationOptions(allow_interrupted=True))
    assert np.all(np.isfinite(run.result.positions()))


def test_capture_configuration_of_another_format_is_a_clear_error(
        session: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    copy = tmp_path / "s"
    shutil.copytree(session, copy)
    journal = copy / "journal.jsonl"
    lines = journal.read_text().splitlines(keepends=True)
    start = json.loads(lines[0])
    start["capture"]["burst"]["taper_ms"] = 5.0  # a key this version does not know
    journal.write_text(json.dumps(start) + "\n" + "".join(lines[1:]))
    assert main(["calibrate", str(copy), "--out", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "micam: error:" in err and "Traceback" not in err
    assert "burst.taper_ms: unknown key 'taper_ms'" in err and "version of micam" in err


@pytest.fixture(scope="module")
def measurements(session: Path):
    from calibration.pipeline import measure

    return measure(session)


def _mean_error(solution, measurements, truth: dict) -> float:
    true = {m["id"]: m["position_m"] for m in truth["microphones"]}
    mics = np.array([true[int(i)] for i in measurements.data.mic_ids])
    return float(np.mean(np.linalg.norm(solution.positions_m - mics, axis=1)))


def test_single_pose_has_no_mirror_or_runaway_solution(measurements, truth: dict) -> None:
    from calibration.pipeline import solve

    for pose in range(len(measurements.located)):
        sol = solve(measurements, CalibrationOptions(latency="none"), poses=np.array([pose]))
        # on the camera's side of the rig, and close: a mirror would be ~1.5 m away
        assert _mean_error(sol, measurements, truth) < 5e-3
        assert np.all(sol.positions_m[:, 2] < 0.05)


def test_reflection_outliers_leave_the_accuracy_unchanged(measurements, truth: dict) -> None:
    import dataclasses

    from calibration.pipeline import solve

    clean = _mean_error(solve(measurements, CalibrationOptions()), measurements, truth)
    rng = np.random.default_rng(5)
    tof = measurements.tofs.tof_s.copy()
    hit = rng.random(tof.shape) < 0.05
    tof[hit] += rng.uniform(0.3e-3, 3e-3, hit.sum())  # late reflection paths
    corrupted = dataclasses.replace(
        measurements, tofs=dataclasses.replace(measurements.tofs, tof_s=tof))
    sol = solve(corrupted, CalibrationOptions())
    assert _mean_error(sol, corrupted, truth) < clean * 1.1 + 0.02e-3
    assert sol.outliers.sum() >= hit.sum() * 0.95


def test_prior_geometry_in_its_own_frame_is_placed_by_one_pose(measurements, truth: dict
                                                               ) -> None:
    from scipy.spatial.transform import Rotation

    from calibration.pipeline import solve
    from calibration.solve.solver import PriorGeometry

    true = {m["id"]: m["position_m"] for m in truth["microphones"]}
    mics = np.array([true[int(i)] for i in measurements.data.mic_ids])
    R = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    own_frame = (mics - 0.1) @ R.T + np.array([1.0, 2.0, 3.0])  # a CAD frame of its own
    sol = solve(measurements, CalibrationOptions(latency="none", prior=PriorGeometry(own_frame)),
                poses=np.array([0]))
    errors = np.linalg.norm(sol.positions_m - mics, axis=1)
    assert errors.mean() < 2e-3
    # a rigid prior keeps the shape exactly: every error is the same rigid motion
    assert np.std(errors) < 0.5e-3


def test_prior_from_acoular_xml_on_the_command_line(session: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    first = tmp_path / "first.json"
    xml = tmp_path / "mics.xml"
    assert main(["calibrate", str(session), "--out", str(first), "--acoular-xml", str(xml),
                 "--no-joint"]) == 0
    again = tmp_path / "again.json"
    assert main(["calibrate", str(session), "--out", str(again), "--prior", str(xml),
                 "--prior-std-mm", "0.5", "--no-joint"]) == 0
    a, b = (np.array([m["position_m"] for m in json.loads(p.read_text())["microphones"]])
            for p in (first, again))
    assert np.abs(a - b).max() < 0.5e-3
    assert main(["calibrate", str(session), "--out", str(tmp_path / "x.json"),
                 "--prior-std-mm", "1"]) == 2
    assert "--prior-std-mm needs --prior" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text('{"microphones": [{"id": 0, "position_m": [0, 0, 0]}]}')
    assert main(["calibrate", str(session), "--out", str(tmp_path / "y.json"),
                 "--prior", str(bad)]) == 2
    assert "lacks microphones" in capsys.readouterr().err


def test_measuring_again_reuses_each_pose_and_image(session: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A long-running process with a memo (the worker's live jobs) decodes, searches and
    correlates every file once: the second measurement of the same files reads none of them."""
    from acquisition.contracts.session import SessionReader
    from calibration.pipeline import WorkMemo, measure

    options = CalibrationOptions(memo=WorkMemo())
    first = measure(session, options)

    def refuse(*args, **kwargs):
        raise AssertionError("a file was read again")

    monkeypatch.setattr(SessionReader, "read_recording", refuse)
    monkeypatch.setattr(SessionReader, "read_image", refuse)
    again = measure(session, options)
    np.testing.assert_array_equal(again.tofs.tof_s, first.tofs.tof_s)
    np.testing.assert_array_equal(again.tofs.reference_tof_s, first.tofs.reference_tof_s)
    # the same corners; OpenCV's camera fit itself repeats to about 1e-13 m
    np.testing.assert_allclose(again.speakers.positions_m, first.speakers.positions_m,
                               rtol=0, atol=1e-9)
    with pytest.raises(AssertionError, match="read again"):  # other settings: not remembered
        measure(session, replace(options, band_hz=(500.0, 18_000.0)))


def test_the_matched_weighting_is_taken_only_where_the_recordings_show_free_field(
        session: Path, tmp_path: Path) -> None:
    """Weighting "auto": the ideal world's recordings hold the direct sound and noise alone
    (echo ratio 1), so their times of flight are correlated with the matched weighting, the
    maximum-likelihood one there; a room's reflections (echo ratio far above 1) keep the
    compact one. A weighting asked for is kept."""
    from calibration.pipeline import FREE_FIELD_ECHO_RATIO, measure
    from micam.simulated import record_simulated_session
    from sim.capture import SimulationOptions

    free = measure(session)
    assert free.tofs.echo_ratio() == pytest.approx(1.0, abs=FREE_FIELD_ECHO_RATIO - 1.0)
    assert free.weighting == "matched"
    room_path = tmp_path / "room"
    record_simulated_session(room_path, SimulationOptions(
        array="scatter48", poses=3, mls_order=9, seed=3, effects=("room",)))
    room = measure(room_path)
    assert room.tofs.echo_ratio() > 10.0
    assert room.weighting == "compact"
    assert measure(session, CalibrationOptions(weighting="compact")).weighting == "compact"


def test_the_echo_ratio_skips_dead_channels_and_is_nan_without_noise() -> None:
    """A dead channel's NaN energies leave the pooled ratio to the others; recordings with no
    noise before their direct peaks give NaN (which "auto" reads as no free field)."""
    from calibration.acoustic.times_of_flight import SessionTofs

    shape = (2, 3, 4)
    echo, lead = np.full(shape, 3.0), np.full(shape, 2.0)
    echo[0, 0, 0] = lead[0, 0, 0] = np.nan
    nothing = np.zeros(shape)
    tofs = SessionTofs(nothing, nothing, nothing, nothing, nothing[..., 0], nothing[..., 0],
                       nothing[..., None], nothing, 2.0, echo, lead, nothing, nothing,
                       np.ones(shape[2]))
    assert tofs.echo_ratio() == pytest.approx(1.5)
    assert tofs.echo_ratio([1]) == pytest.approx(1.5)
    silent = replace(tofs, lead_energy=np.zeros(shape))
    assert np.isnan(replace(silent, echo_energy=np.zeros(shape)).echo_ratio())


def test_a_subset_fit_with_c_per_pose_images_every_pose(measurements) -> None:
    """The joint fit of some poses fits c for those only; the rest (held out, or used by the
    response estimate) take the session's c instead of another pose's or an IndexError."""
    from calibration.pipeline import calibrate_measured

    fitted = np.array([0, 2])
    run = calibrate_measured(measurements, CalibrationOptions(speed_of_sound_per_pose=True),
                             poses=fitted)
    assert run.bundle is not None and run.result.microphone_responses is not None
    bundle = run.bundle
    assert bundle.state.speeds_of_sound_m_s.size == fitted.size
    for k in range(len(measurements.located)):
        expected = (bundle.state.speeds_of_sound_m_s[list(fitted).index(k)] if k in fitted
                    else bundle.state.speed_of_sound_m_s)
        assert bundle.speed_of_sound_at(k) == pytest.approx(expected, abs=1e-9)


def test_a_result_whose_times_of_flight_are_mostly_too_faint_reads_back(
        session: Path, tmp_path: Path) -> None:
    """More than half the located times of flight with an infinite predicted std (a short
    burst in a noisy room: a clean 3-pose realistic session with MLS order 10) made the
    median infinite, written to result.json as null, which the result's own model refused to
    read back (micam image and the page could not show that calibration)."""
    from calibration.result_assembly import _finite_median
    from calibration.result import CalibrationResult

    assert _finite_median(np.array([np.inf, np.inf, 1e-8])) is None
    assert _finite_median(np.array([np.inf, 2e-8, 1e-8])) == 2e-8
    out = tmp_path / "result.json"
    assert main(["calibrate", str(session), "--out", str(out), "--no-joint"]) == 0
    document = json.loads(out.read_text())
    document["tof_quality"]["median_predicted_std_s"] = None
    assert CalibrationResult.model_validate(document).tof_quality.median_predicted_std_s is None


def test_a_lent_reference_recording_measures_a_speaker_as_its_own_does(measurements) -> None:
    """Speaker 0's bursts correlated with speaker 3's reference recording (every speaker plays
    the same burst through the same kind of driver) give its times of flight to within their
    noise, less one constant; the memo keeps the two apart."""
    from calibration.acoustic.times_of_flight import TofMemo, measure_session_tofs

    data, own = measurements.data, measurements.tofs
    memo = TofMemo(64)
    first = measure_session_tofs(data, 343.0, memo=memo)
    lent = measure_session_tofs(data, 343.0, memo=memo, templates=np.array([3, 1, 2, 3, 4, 5]))
    assert np.array_equal(lent.tof_s[:, 1:], first.tof_s[:, 1:])
    difference = lent.tof_s[:, 0] - first.tof_s[:, 0]
    assert not np.array_equal(difference, np.zeros_like(difference))  # measured again
    scatter = np.nanstd(difference - np.nanmedian(difference))
    assert scatter < 2 * np.nanmedian(own.std_s[:, 0])
    assert abs(np.nanmedian(difference)) < 50e-9  # the simulated drivers are alike


def test_speakers_measured_again_keep_what_was_left_out_and_exchange_whole() -> None:
    """`with_speakers_from` takes a speaker's new measurements but keeps its left-out ones
    (NaN) left out; `exchanged` moves every array of the two speakers, the reference
    microphone's too."""
    from calibration.acoustic.times_of_flight import SessionTofs

    shape = (2, 3, 4)

    def tofs(value: float) -> SessionTofs:
        full = np.full(shape, value) + np.arange(3)[None, :, None]
        return SessionTofs(full, full, full, full, full[..., 0], full[..., 0], full[..., None],
                           full, 2.0, full, full, full, full, np.ones(shape[2]))

    old, new = tofs(0.0), tofs(10.0)
    old.tof_s[0, 1, 2] = np.nan
    taken = old.with_speakers_from(new, [1])
    assert np.isnan(taken.tof_s[0, 1, 2]) and taken.tof_s[1, 1, 2] == 11.0
    assert np.all(taken.tof_s[:, [0, 2]] == old.tof_s[:, [0, 2]])
    assert np.all(taken.snr_db[:, 1] == 11.0) and np.all(taken.reference_tof_s[:, 1] == 11.0)
    swapped = taken.exchanged(0, 1)
    assert np.isnan(swapped.tof_s[0, 0, 2]) and np.all(swapped.impulses[:, 1] == 0.0)
    assert np.all(swapped.reference_std_s[:, 0] == 11.0) and np.all(swapped.tof_s[:, 2] == 2.0)


def test_a_spoiled_speaker_is_not_measured_again_without_a_sound_one_to_lend(
        measurements) -> None:
    """With no sound speaker left to lend its reference recording, the spoiled speaker is
    not measured again: the caller leaves it out."""
    from calibration.checks.fit_checks import SourceResiduals
    from calibration.pipeline import _on_lent_reference, solve

    options = CalibrationOptions()
    n_speaker = measurements.data.n_speakers
    residuals = SourceResiduals.of(solve(measurements, options), len(measurements.located),
                                   n_speaker)
    nobody = np.zeros(n_speaker, dtype=bool)
    assert _on_lent_reference(measurements, options, None, residuals, 2, nobody) is None
    lent = _on_lent_reference(measurements, options, None, residuals, 2, ~nobody)
    assert lent is not None and list(lent[0].lent_references) == [2] and lent[2] != 2
    assert lent[0].lent_references[2].lender == lent[2]


def test_impulses_of_a_lent_speaker_move_back_by_its_emission_delay(measurements) -> None:
    """A speaker on a lent reference recording has its impulses moved back by its emission
    delay (the camera-frozen shift plus the joint fit's own), so that the responses read
    them as they read a speaker correlated with its own recording; no other moves."""
    from types import SimpleNamespace

    from calibration.pipeline import LentReference, _emission_aligned

    lent = replace(measurements, lent_references={2: LentReference(0, 1.0e-6)})
    delays = np.array([0.0, 0.0, 0.5e-6, 0.0, 0.0, 0.0])
    bundle = SimpleNamespace(state=SimpleNamespace(speaker_delays_s=delays))
    aligned = _emission_aligned(lent, bundle)  # type: ignore[arg-type]
    before = measurements.tofs.impulse_first_lag
    moved = before[:, 2] - aligned.tofs.impulse_first_lag[:, 2]
    assert np.allclose(moved, 1.5e-6 * measurements.data.fs)
    others = [0, 1, 3, 4, 5]
    assert np.array_equal(aligned.tofs.impulse_first_lag[:, others], before[:, others])
