"""`micam batch` on a real LocalCluster of 2 worker processes (distributed).

Six small simulated sessions (three worlds, each also copied, so that six cells run) and a
directory that is no session. Each session's result.json must be bit for bit what calibrating
it alone gives (`micam calibrate`'s code in a process of its own, with the one-thread BLAS and
OpenMP pools that Dask's nanny gives its workers; only the timings differ); a worker killed in
the middle of a task must be survived; a resumed batch must recompute only what is missing;
the bad session must fail its cell alone, with its message.
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
from micam.cli import EXIT_FAILED, main

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
    from micam.batch import runner

    monkeypatch.setattr(runner, "CONNECT_TIMEOUT_S", 1.0)
    with pytest.raises(UserError, match="--scheduler tcp://127.0.0.1:9: cannot reach"):
        run_batch(sessions[:1], tmp_path / "out", scheduler="tcp://127.0.0.1:9",
                  progress=False)


def test_calibrate_options_are_checked_before_any_work(sessions: list[Path],
                                                       tmp_path: Path) -> None:
    with pytest.raises(UserError, match="calibrate options: .*--latency"):
        run_batch(sessions[:1], tmp_path / "out", ["--latency", "sometimes"], progress=False)
