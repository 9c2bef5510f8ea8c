"""`micam batch` on a real LocalCluster of 2 worker processes (distributed).

Six small simulated sessions (three worlds, each also copied, so that six cells run) and a
directory that is no session. Each session's result.json must be bit for bit what calibrating
it alone gives (`micam calibrate`'s code in a process of its own, with the one-thread BLAS and
OpenMP pools that Dask's nanny gives its workers; only the timings differ); a worker killed in
the middle of a task must be survived; a resumed batch must recompute only what is missing;
the bad session must fail its cell alone, with its message. The studies' cells (the bands of
`micam study`, the calibrations of `evaluate-imaging --folds`) run on the same cluster and
must give the numbers of the serial path.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from acquisition.contracts.errors import UserError
from micam.batch import BatchOutcome, run_batch
from micam.cli import EXIT_FAILED, EXIT_USAGE, main

pytestmark = pytest.mark.slow  # a Dask cluster and calibrated simulated sessions (seconds each)

SEEDS = (3, 4, 5)
ALONE = """import json, sys
from micam.calibrating import calibrate_session
from micam.cli import build_parser
for session, out in json.loads(sys.argv[1]):
    calibrate_session(build_parser().parse_args(["calibrate", session, "--out", out]),
                      report=False)
"""
"""Calibrate (session, result) pairs as `micam calibrate SESSION --out RESULT` does."""
ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
"""The thread pools of a Dask worker (distributed.nanny.pre-spawn-environ)."""


def _content(path: Path) -> dict:
    """A result.json without its timings (the only thing that differs from run to run)."""
    document = json.loads(Path(path).read_text())
    document.pop("timings_s")
    return document


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three simulated sessions (48 microphones, 3 poses, MLS order 8) and a copy of each."""
    from micam.simulated import record_simulated_session
    from sim.capture import SimulationOptions

    root = tmp_path_factory.mktemp("batch-sessions")
    made = []
    for seed in SEEDS:
        session = root / f"seed{seed}"
        record_simulated_session(session, SimulationOptions(array="scatter48", poses=3,
                                                            mls_order=8, seed=seed))
        shutil.copytree(session, root / f"seed{seed}-copy")
        made += [session, root / f"seed{seed}-copy"]
    return made


@pytest.fixture(scope="module")
def not_a_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("bad") / "not-a-session"


@pytest.fixture(scope="module")
def alone(sessions: list[Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict]:
    """Each simulated world calibrated alone, by session name (a copy has its original's)."""
    out = tmp_path_factory.mktemp("alone")
    originals = [s for s in sessions if not s.name.endswith("-copy")]
    pairs = [(str(s), str(out / f"{s.name}.json")) for s in originals]
    subprocess.run([sys.executable, "-c", ALONE, json.dumps(pairs)], check=True,
                   env={**os.environ, **ONE_THREAD})
    results = {s.name: _content(out / f"{s.name}.json") for s in originals}
    return {s.name: results[s.name.removesuffix("-copy")] for s in sessions}


@pytest.fixture(scope="module")
def cluster() -> Iterator[str]:
    """The address of a LocalCluster of 2 worker processes, one thread each."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None) as local:
        yield local.scheduler_address


@pytest.fixture(scope="module")
def first_batch(sessions: list[Path], not_a_session: Path, cluster: str,
                tmp_path_factory: pytest.TempPathFactory) -> BatchOutcome:
    not_a_session.mkdir()
    return run_batch([*sessions, not_a_session], tmp_path_factory.mktemp("batch") / "out",
                     scheduler=cluster, progress=False)


def _assert_same_as_alone(outcome: BatchOutcome, alone: dict[str, dict]) -> None:
    ok = [r for r in outcome.rows if r.status == "ok"]
    assert {r.cell for r in ok} == set(alone)
    for row in ok:
        assert row.result is not None
        assert _content(Path(row.result)) == alone[row.cell], row.cell


def test_a_batch_gives_each_session_its_result_alone(first_batch: BatchOutcome,
                                                     alone: dict[str, dict]) -> None:
    _assert_same_as_alone(first_batch, alone)
    for row in first_batch.rows[:-1]:
        assert row.mean_mic_error_mm is not None and 0 < row.mean_mic_error_mm < 2
        assert row.seconds > 0 and not row.kept
    # a copy is the same world: the same result, so the same error against its truth
    assert first_batch.rows[0].mean_mic_error_mm == first_batch.rows[1].mean_mic_error_mm


def test_a_bad_session_fails_its_cell_alone(first_batch: BatchOutcome,
                                            not_a_session: Path) -> None:
    *good, bad = first_batch.rows
    assert [r.status for r in good] == ["ok"] * 6
    assert bad.status == "failed" and bad.session == str(not_a_session)
    assert "is not a micam session" in bad.message and bad.result is None
    lines = first_batch.csv.read_text().splitlines()
    assert lines[0].startswith("session,cell,status,mean_mic_error_mm,seconds,message")
    assert len(lines) == 8 and lines[-1].startswith(f"{not_a_session},not-a-session,failed,")
    table = json.loads(first_batch.json.read_text())
    assert [r["status"] for r in table["rows"]] == ["ok"] * 6 + ["failed"]
    assert table["options"]["latency"] == "per_board"


def test_a_resumed_batch_recomputes_only_what_is_missing(
        first_batch: BatchOutcome, sessions: list[Path], not_a_session: Path,
        alone: dict[str, dict], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Through the command, on its own LocalCluster: a result deleted and a cell.json
    damaged are recomputed, as is the failed cell; the others are kept untouched."""
    out = tmp_path / "moved"
    shutil.copytree(first_batch.csv.parent, out)
    (out / "seed4" / "result.json").unlink()
    (out / "seed5" / "cell.json").write_text("{")
    kept = ("seed3", "seed3-copy", "seed4-copy", "seed5-copy")
    stamps = {name: (out / name / "result.json").stat().st_mtime_ns for name in kept}
    status = main(["batch", *map(str, sessions), str(not_a_session), "--out", str(out),
                   "--workers", "2", "--quiet"])
    assert status == EXIT_FAILED
    printed = capsys.readouterr().out
    assert "7 sessions: 6 ok (4 kept from an earlier run), 1 failed" in printed
    rows = {r["cell"]: r for r in json.loads((out / "batch.json").read_text())["rows"]}
    assert {name for name, r in rows.items() if r["kept"]} == set(kept)
    assert {name: (out / name / "result.json").stat().st_mtime_ns for name in kept} == stamps
    for name in ("seed4", "seed5"):
        assert rows[name]["status"] == "ok"
        assert _content(out / name / "result.json") == alone[name]
    assert rows[kept[0]]["result"] == str(out / kept[0] / "result.json")


def test_a_worker_killed_mid_batch_is_survived(sessions: list[Path], cluster: str,
                                              alone: dict[str, dict], tmp_path: Path) -> None:
    from distributed import Client

    killed: list[int] = []

    def kill_a_busy_worker() -> None:
        with Client(cluster) as client:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                busy = [w for w, keys in client.processing().items()
                        if any(str(k).startswith("calibrate-") for k in keys)]
                if busy:
                    time.sleep(0.3)  # into the task
                    pid = client.run(os.getpid, workers=busy[:1])[busy[0]]
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                    return
                time.sleep(0.02)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    outcome = run_batch(sessions, tmp_path / "out", scheduler=cluster, progress=False)
    killer.join()
    assert killed, "no worker was busy to be killed"
    assert [r.status for r in outcome.rows] == ["ok"] * 6
    _assert_same_as_alone(outcome, alone)
    with Client(cluster) as client:
        client.wait_for_workers(2, timeout=30)
        assert killed[0] not in client.run(os.getpid).values()


def test_an_out_among_the_sessions_is_refused_before_any_work(sessions: list[Path]) -> None:
    with pytest.raises(UserError, match="outside the sessions' directories"):
        run_batch(sessions[:1], sessions[0].parent, progress=False)


def test_a_scheduler_that_does_not_answer_is_named(sessions: list[Path], tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from micam import cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(UserError, match="--scheduler tcp://127.0.0.1:9: cannot reach"):
        run_batch(sessions[:1], tmp_path / "out", scheduler="tcp://127.0.0.1:9",
                  progress=False)


def test_calibrate_options_are_checked_before_any_work(sessions: list[Path],
                                                       tmp_path: Path) -> None:
    with pytest.raises(UserError, match="calibrate options: .*--latency"):
        run_batch(sessions[:1], tmp_path / "out", ["--latency", "sometimes"], progress=False)


STUDY = ["--bands", "0.4-0.6", "0.6-1.0", "--poses", "3", "--sources", "3", "6",
         "--trials", "1", "--array", "scatter48", "--mls-order", "8", "--seed", "7"]
"""A tiny `micam study`: two bands (two cells), a 3-pose session each (the fewest whose
cameras calibrate), a subset of 3 sources and one of 6 (the paper's model, then latencies)."""


@pytest.mark.slow
def test_the_study_runs_its_bands_on_the_cluster_with_the_serial_numbers(
        cluster: str, tmp_path: Path) -> None:
    """Each band's rows bit for bit those of its session studied here (what `micam study`
    does after simulating it), with the workers' one BLAS thread (with more, the bound's sums
    are taken in another order: ~1e-13 apart), in the order of the bands."""
    from calibration._blas import single_threaded_blas
    from micam.commands.study import band_rows

    out = tmp_path / "study"
    assert main(["study", "--out", str(out), *STUDY, "--scheduler", cluster]) == 0
    study = json.loads((out / "study.json").read_text())
    assert [band["band_m"] for band in study] == [[0.4, 0.6], [0.6, 1.0]]
    for band in study:
        session = out / "band-{:.1f}-{:.1f}".format(*band["band_m"])  # made on a worker
        truth = json.loads((session / "truth.json").read_text())
        with single_threaded_blas():
            serial = band_rows(session, truth, [3, 6], trials=1, seed=7)
        assert band == serial | {"band_m": band["band_m"]}
    assert [row["latency"] for row in study[0]["rows"]] == ["none", "per_board"]
    assert study[0]["rows"] != study[1]["rows"]


@pytest.mark.slow
def test_the_folds_run_their_calibrations_on_the_cluster_with_the_serial_numbers(
        sessions: list[Path], cluster: str) -> None:
    """`cross_validate` with the cluster's `ClusterMap` (as `evaluate-imaging --folds 3
    --scheduler` runs it): the in-sample and the three held-out calibrations, each with its
    imaging, as four tasks; bit for bit those made here. (Blocks of 1024 samples: the
    sessions' MLS bursts are shorter than the command's 4096.)"""
    from distributed import Client

    from calibration._blas import single_threaded_blas
    from imaging import load_geometry
    from imaging.csm import WelchOptions
    from imaging.evaluate import ImagingSettings
    from imaging.holdout import cross_validate
    from micam.cluster import ClusterMap

    session = sessions[0]
    settings = ImagingSettings(WelchOptions(block_size=1024), band_lo_hz=9000.0,
                               band_hi_hz=10000.0, spacing_m=0.02)  # one band: 9514 Hz
    truth = load_geometry(session / "truth.json")
    with Client(cluster) as client:
        dask = cross_validate(session, 3, settings, truth=truth,
                              mapper=ClusterMap(client, "folds")).to_json()
    with single_threaded_blas():
        serial = cross_validate(session, 3, settings, truth=truth).to_json()
    assert dask == serial
    assert dask["folds"] == [[0], [1], [2]]
    assert dask["held_out"]["overall"]["count"] == 18  # 3 poses x 6 speakers, one band
    assert dask["held_out"] != dask["in_sample"]


@pytest.mark.parametrize("command", [
    ["study", "--out", "OUT", "--workers", "2"],
    ["evaluate-imaging", "SESSION", "--folds", "3", "--workers", "2"]])
def test_workers_beside_a_scheduler_are_refused(
        command: list[str], tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    argv = [str(tmp_path / "s") if a in ("OUT", "SESSION") else a for a in command]
    assert main([*argv, "--scheduler", "tcp://127.0.0.1:9"]) == EXIT_USAGE
    assert "--workers" in capsys.readouterr().err
