"""The whole hand-off as processes: daemon, workers, a scripted capture, kills and a restart.

The kill points are handshakes: a harness worker reports when it is inside the final job
(worker_harness.py), and the test kills it there. Every wait is bounded.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from acquisition.daemon.outbox import JobRecord
from calibration.report import FIGURES
from acquisition.contracts.protocol import CalibrationEvent, JobEvent
from tests.acquisition.daemon.helpers import DaemonProcess, capture_all

from .helpers import (
    Holds,
    daemon_toml,
    start_worker,
    stop_worker,
    wait_calibration,
    wait_workers,
)


def _final_job(root: Path) -> JobRecord:
    (path,) = (root / "sessions.outbox").glob("*.final.json")
    return JobRecord.model_validate_json(path.read_text())


def _stored_once(session: Path, job: JobRecord) -> None:
    """One result beside the session, the one the outbox records, with its report (the files
    `micam calibrate` writes)."""
    names = {p.name for p in (session / "calibration").iterdir()}
    assert names - {"live.json", "live_history.jsonl"} == {"result.json", "report.md", *FIGURES}
    assert "![geometry](geometry.png)" in (session / "calibration" / "report.md").read_text()
    data = (session / "calibration" / "result.json").read_bytes()
    assert hashlib.sha256(data).hexdigest() == job.result_sha256
    result = json.loads(data)
    truth = json.loads((session / "truth.json").read_text())
    assert len(result["microphones"]) == len(truth["microphones"])


@pytest.mark.slow
def test_a_worker_killed_inside_the_final_job_is_replaced_by_the_other(tmp_path: Path) -> None:
    holds = Holds(tmp_path)
    daemon = DaemonProcess(daemon_toml(tmp_path), tmp_path)
    workers = {name: start_worker(tmp_path, name, holds) for name in ("wa", "wb")}
    try:
        daemon.wait_message("READY=1")
        with daemon.client() as client:
            wait_workers(client, 2)
            stream = client.subscribe()
            session = Path(client.request("session.start", poses=3)["session"]["path"])
            capture_all(client)
            held_by = holds.wait()
            workers[held_by].kill()
            workers[held_by].wait(30)
            events: list = []
            status = wait_calibration(client, stream, events)
            stream.close()
        assert status.calibration.failed == 0
    finally:
        for proc in workers.values():
            stop_worker(proc)
        daemon.proc.terminate()
        daemon.wait_exit()
        holds.close()
    job = _final_job(tmp_path)
    (other,) = set(workers) - {held_by}
    assert (job.state, job.attempt) == ("done", 2)
    _stored_once(session, job)
    finals = [e for e in events if isinstance(e, CalibrationEvent)]
    assert [(e.attempt, e.worker) for e in finals] == [(2, other)]
    requeued = [e for e in events if isinstance(e, JobEvent) and e.state == "requeued"]
    assert requeued and held_by in requeued[0].reason


@pytest.mark.slow
def test_a_job_pending_across_a_daemon_restart_completes(tmp_path: Path) -> None:
    holds = Holds(tmp_path)
    config = daemon_toml(tmp_path)
    daemon = DaemonProcess(config, tmp_path)
    holder = start_worker(tmp_path, "wa", holds)
    try:
        daemon.wait_message("READY=1")
        with daemon.client() as client:
            wait_workers(client, 1)
            session = Path(client.request("session.start", poses=3)["session"]["path"])
            capture_all(client)
        assert holds.wait() == "wa"
        leased = _final_job(tmp_path)
        assert (leased.state, leased.attempt) == ("leased", 1)
    finally:
        daemon.kill()  # SIGKILL with the final job leased
        holder.kill()
        holder.wait(30)
    daemon = DaemonProcess(config, tmp_path)
    worker = start_worker(tmp_path, "wb", holds)  # the token is gone: wb does not hold
    try:
        daemon.wait_message("READY=1")
        with daemon.client() as client:
            stream = client.subscribe()
            events: list = []
            wait_calibration(client, stream, events)
            stream.close()
    finally:
        stop_worker(worker)
        daemon.proc.terminate()
        daemon.wait_exit()
        holds.close()
    job = _final_job(tmp_path)
    assert (job.state, job.attempt) == ("done", 2)
    _stored_once(session, job)
    assert [(e.attempt, e.worker) for e in events if isinstance(e, CalibrationEvent)] == \
        [(2, "wb")]
