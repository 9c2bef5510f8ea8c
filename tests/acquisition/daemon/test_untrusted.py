"""What the daemon trusts: nothing that arrives from a file or a message. Journals that point
outside their session, planted job files, links out of a session, forged results, workers of
another protocol version; each is refused with a reason and the daemon carries on."""

from __future__ import annotations

import hashlib
import json
import os
import time
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
import zmq

from acquisition.daemon.config import WorkersConfig
from acquisition.daemon.endpoints import beside
from acquisition.daemon.files import FileServer
from acquisition.contracts.job_messages import JobFile, JournalPrefix
from acquisition.daemon.outbox import JobRecord
from acquisition.contracts.session import SessionReader, SessionWriter
from acquisition.contracts.session import sha256_file

from .helpers import FakeWorker, ThreadDaemon, capture_all, small_config, wait_state

NOW = datetime(2026, 1, 1, tzinfo=UTC).isoformat()


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[ThreadDaemon]:
    running = ThreadDaemon(small_config(tmp_path, workers=WorkersConfig(live=False,
                                                                        max_attempts=5)))
    yield running
    running.stop()


def _jobs(daemon: ThreadDaemon) -> FakeWorker:
    return FakeWorker(beside(daemon.config.sockets.control, "jobs"))


# -- session content ---------------------------------------------------------------------


def _forged_journal(daemon: ThreadDaemon, name: str, session_id: str, path: str) -> None:
    """An interrupted session of this daemon's configuration whose journal someone edited."""
    capture = daemon.hardware.config.model_dump(mode="json")
    SessionWriter.create(daemon.config.session_root / name, capture=capture,
                         session_id=name).close()
    journal = daemon.config.session_root / name / "journal.jsonl"
    start, *_ = journal.read_text().splitlines()
    first = json.loads(start)
    first["session_id"] = session_id
    hostname = Path("/etc/hostname").read_bytes() if Path("/etc/hostname").exists() else b"x"
    records = [first,
               {"seq": 1, "time_utc": NOW, "kind": "step_begin", "step": "reference/0",
                "attempt": 1, "dir": "references/0-a1"},
               {"seq": 2, "time_utc": NOW, "kind": "file", "step": "reference/0", "attempt": 1,
                "path": path, "sha256": hashlib.sha256(hostname).hexdigest(),
                "bytes": len(hostname), "role": "recording", "meta": {}},
               {"seq": 3, "time_utc": NOW, "kind": "step_end", "step": "reference/0",
                "attempt": 1}]
    journal.write_text("".join(json.dumps(r) + "\n" for r in records))


@pytest.mark.parametrize(("session_id", "path"), [
    ("s1", "../../../../etc/hostname"),
    ("s1", "/etc/hostname"),
    ("s1", "references/0-a1/../../../x.wav"),
    ("s1", "poses/0000-a1/speaker_0.wav"),  # a file of another attempt's directory
    ("../ESCAPED", "references/0-a1/speaker_0.wav"),
    ("has space", "references/0-a1/speaker_0.wav"),
])
def test_a_journal_pointing_outside_its_session_is_refused(
        daemon: ThreadDaemon, session_id: str, path: str) -> None:
    _forged_journal(daemon, "s1", session_id, path)
    with daemon.client() as client:
        reply = client.exchange([json.dumps({"v": 2, "command": "session.start",
                                             "args": {"resume": "s1"}}).encode()])
        assert not reply.ok and reply.error is not None
        assert reply.error.code == "session_error"
        assert "journal.jsonl" in reply.error.message
        assert client.status().state == "idle"


def _record(root: Path, **changes: object) -> dict:
    record = {"job_id": "s1.final", "kind": "final", "session_id": "s1",
              "session_path": str(root / "sessions" / "s1"), "poses": 1,
              "journal": {"bytes": 10, "sha256": "0" * 64}, "files": [], "state": "pending",
              "attempt": 0, "worker": None, "created_utc": NOW, "updated_utc": NOW,
              "result_sha256": None, "reason": ""}
    return {**record, **changes}


@pytest.mark.slow
def test_planted_job_files_are_ignored_and_the_daemon_keeps_serving(tmp_path: Path) -> None:
    outbox = tmp_path / "sessions.outbox"
    outbox.mkdir()
    planted = {
        "a b.final": _record(tmp_path, job_id="a b.final"),
        "x.final": _record(tmp_path, job_id="x.final", session_id="../ESCAPED"),
        "y.final": _record(tmp_path, job_id="y.final", session_path="/etc"),
        "z.final": _record(tmp_path, job_id="other.final"),  # not its own file name
        "w.final": _record(tmp_path, job_id="w.final",
                           files=[{"path": "../../etc/hostname", "bytes": 3,
                                   "sha256": "0" * 64}]),
    }
    for name, record in planted.items():
        (outbox / f"{name}.json").write_text(json.dumps(record))
    running = ThreadDaemon(small_config(tmp_path))
    worker = _jobs(running)
    try:
        worker.send({"v": 2, "type": "ready", "worker": "w"})
        with pytest.raises(AssertionError, match="no 'job' message"):
            worker.receive("job", timeout_s=1.0)
        with running.client() as client:
            status = client.status()
        assert status.calibration.pending == 0 and [w.name for w in status.calibration.workers
                                                    ] == ["w"]
        assert not (tmp_path.parent / "ESCAPED.final.json").exists()
    finally:
        worker.close()
        running.stop()


def _plant(kind: str, session: Path, secret: Path) -> None:
    """refmic-a1/cam0.png of `session` made to reach `secret` (or to block a reader)."""
    if kind == "symlink":
        (session / "refmic-a1").mkdir(parents=True)
        (session / "refmic-a1" / "cam0.png").symlink_to(secret)
    elif kind == "linked-directory":  # the link in the middle of the path
        session.mkdir(parents=True)
        (secret.parent / "elsewhere").mkdir()
        (secret.parent / "elsewhere" / "cam0.png").write_bytes(secret.read_bytes())
        (session / "refmic-a1").symlink_to(secret.parent / "elsewhere")
    elif kind == "hard-link":
        (session / "refmic-a1").mkdir(parents=True)
        os.link(secret, session / "refmic-a1" / "cam0.png")
    else:  # a FIFO: opening it for reading would block the daemon
        (session / "refmic-a1").mkdir(parents=True)
        os.mkfifo(session / "refmic-a1" / "cam0.png")


@pytest.mark.parametrize(("kind", "why"), [
    ("symlink", "symbolic link"), ("linked-directory", "refmic-a1 is a symbolic link"),
    ("hard-link", "2 hard links"), ("fifo", "not a regular file")])
def test_the_file_server_serves_no_link_and_no_fifo(tmp_path: Path, kind: str, why: str
                                                   ) -> None:
    session = tmp_path / "s1"
    secret = tmp_path / "secret"
    secret.write_bytes(b"not for workers")
    _plant(kind, session, secret)
    job = JobRecord(job_id="s1.final", kind="final", session_id="s1",
                    session_path=str(session), poses=0,
                    journal=JournalPrefix(bytes=1, sha256="0" * 64),
                    files=[JobFile(path="refmic-a1/cam0.png", bytes=15, sha256="0" * 64)],
                    created_utc=datetime.fromisoformat(NOW),
                    updated_utc=datetime.fromisoformat(NOW))
    context = zmq.Context()
    router = context.socket(zmq.ROUTER)
    router.bind(f"ipc://{tmp_path}/files")
    dealer = context.socket(zmq.DEALER)
    dealer.connect(f"ipc://{tmp_path}/files")
    try:
        dealer.send_json({"v": 2, "type": "fetch", "job_id": "s1.final",
                          "path": "refmic-a1/cam0.png", "offset": 0, "length": 15})
        assert router.poll(10_000)
        FileServer(router, {"s1.final": job}.get).serve()
        assert dealer.poll(10_000)
        reply = json.loads(dealer.recv_multipart()[0])
    finally:
        context.destroy(linger=0)
    assert reply["type"] == "fetch_error" and why in reply["reason"], reply


# -- workers -----------------------------------------------------------------------------


def _result(session: Path, **changes: object) -> dict:
    """A result that describes `session` (from its truth), with `changes`."""
    truth = json.loads((session / "truth.json").read_text())
    reader = SessionReader(session)
    result = {
        "session_id": reader.session_id,
        "microphones": [{"id": m["id"], "position_m": m["position_m"], "std_m": [1e-4] * 3,
                         "board": m["board"]} for m in truth["microphones"]],
        "speed_of_sound_m_s": truth["speed_of_sound_m_s"],
        "cameras": [{"name": c["name"]} for c in truth["cameras"]],
        "poses": [{"step": s} for s in reader.steps() if s.startswith("pose/")],
    }
    return {**result, **changes}


def _done(worker: FakeWorker, job: dict, result: bytes) -> dict:
    worker.send({"v": 2, "type": "done", "job_id": job["job_id"], "attempt": job["attempt"],
                 "result_sha256": hashlib.sha256(result).hexdigest()}, result)
    return worker.receive("ack")[0]


@pytest.mark.slow
def test_forged_results_are_refused_and_a_stored_one_keeps_its_checksum(
        daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        session = Path(client.request("session.start", poses=1)["session"]["path"])
        capture_all(client)
        wait_state(client, "idle")
    worker = _jobs(daemon)
    try:
        worker.send({"v": 2, "type": "ready", "worker": "rogue"})
        job, _ = worker.receive("job")
        truth = _result(session)
        one_mic = {**truth, "microphones": truth["microphones"][:1], "speed_of_sound_m_s": 1.0}
        for forged in (one_mic, {**truth, "session_id": "another"},
                       {**truth, "speed_of_sound_m_s": 1.0}):
            ack = _done(worker, job, json.dumps(forged).encode())
            assert not ack["accepted"] and "rejected" in ack["reason"]
            assert not (session / "calibration" / "result.json").exists()
            job, _ = worker.receive("job")  # requeued, and leased to the idle worker again

        # An earlier attempt stored its result, and the daemon stopped before marking the job
        # done; this attempt's bytes differ (timings): the stored file stays, and the outbox
        # records the checksum of what is on disk.
        stored = session / "calibration" / "result.json"
        stored.parent.mkdir(exist_ok=True)
        stored.write_text(json.dumps(truth, indent=2))
        ack = _done(worker, job, json.dumps(truth).encode())
        assert ack["accepted"], ack
    finally:
        worker.close()
    record = JobRecord.model_validate_json(
        (daemon.config.session_root.with_name("sessions.outbox")
         / f"{job['job_id']}.json").read_text())
    assert record.state == "done" and record.result_sha256 == sha256_file(stored).sha256
    assert json.loads(stored.read_text()) == truth


def test_workers_of_another_protocol_version_are_told_why(daemon: ThreadDaemon) -> None:
    worker = _jobs(daemon)
    files = FakeWorker(beside(daemon.config.sockets.control, "files"))
    try:
        worker.send({"v": 3, "type": "ready", "worker": "future"})
        refused, _ = worker.receive("refused", timeout_s=5.0)
        assert "version 3" in refused["reason"]
        worker.send({"type": "ready", "worker": "unversioned"})  # not taken as version 1
        refused, _ = worker.receive("refused", timeout_s=5.0)
        assert "no protocol version" in refused["reason"]
        files.send({"type": "fetch", "job_id": "x", "path": "journal.jsonl", "offset": 0,
                    "length": 1})
        error, _ = files.receive("fetch_error", timeout_s=5.0)
        assert "no protocol version" in error["reason"]
        with daemon.client() as client:
            assert client.status().calibration.workers == []
    finally:
        worker.close()
        files.close()


def test_finished_jobs_are_pruned_from_the_outbox(tmp_path: Path) -> None:
    outbox = tmp_path / "sessions.outbox"
    outbox.mkdir()
    old = (datetime.now(UTC) - timedelta(days=8)).isoformat()
    recent = datetime.now(UTC).isoformat()
    for name, state, when in (("old", "done", old), ("failed", "failed", old),
                              ("new", "done", recent), ("waiting", "pending", old)):
        (outbox / f"{name}.final.json").write_text(json.dumps(_record(
            tmp_path, job_id=f"{name}.final", session_id=name,
            session_path=str(tmp_path / "sessions" / name), state=state, updated_utc=when)))
    running = ThreadDaemon(small_config(tmp_path))
    try:
        with running.client() as client:
            client.status()
    finally:
        running.stop()
    assert sorted(p.name for p in outbox.iterdir()) == ["new.final.json", "waiting.final.json"]


def test_a_job_file_half_written_when_the_daemon_died_does_not_block_the_job(
        tmp_path: Path) -> None:
    outbox = tmp_path / "sessions.outbox"
    outbox.mkdir()
    record = _record(tmp_path)
    (outbox / "s1.final.json").write_text(json.dumps(record))
    (outbox / "s1.final.json.partial").write_text('{"job_id": "s1.fi')  # SIGKILL mid-write
    running = ThreadDaemon(small_config(tmp_path))
    worker = _jobs(running)
    try:
        worker.send({"v": 2, "type": "ready", "worker": "w"})
        job, _ = worker.receive("job", timeout_s=10.0)
        assert job["job_id"] == "s1.final" and job["attempt"] == 1
    finally:
        worker.close()
        running.stop()


def test_a_job_file_waiting_longer_than_any_retry_delay_is_offered_at_once(
        tmp_path: Path) -> None:
    """The wait in a job file is believed only up to the longest retry delay the broker sets:
    an edited record (or a clock set back) cannot hold a job back for years."""
    outbox = tmp_path / "sessions.outbox"
    outbox.mkdir()
    record = _record(tmp_path, not_before_utc="2999-01-01T00:00:00Z")
    (outbox / "s1.final.json").write_text(json.dumps(record))
    running = ThreadDaemon(small_config(tmp_path))
    worker = _jobs(running)
    try:
        worker.send({"v": 2, "type": "ready", "worker": "w"})
        job, _ = worker.receive("job", timeout_s=10.0)
        assert job["job_id"] == "s1.final" and job["attempt"] == 1
    finally:
        worker.close()
        running.stop()


@pytest.mark.slow
def test_a_retryable_failure_is_offered_again_after_a_growing_delay(tmp_path: Path) -> None:
    """A worker's retryable failure is not re-offered at once (all attempts would be spent
    within milliseconds): after `retry_delay_s`, then twice that, and the job's record says
    when; the last attempt's failure gives the job up."""
    config = small_config(tmp_path, workers=WorkersConfig(live=False, max_attempts=3,
                                                          retry_delay_s=1.0))
    running = ThreadDaemon(config)
    try:
        with running.client() as client:
            client.request("session.start", poses=1)
            capture_all(client)
            wait_state(client, "idle")
        worker = _jobs(running)
        try:
            worker.send({"v": 2, "type": "ready", "worker": "flaky"})
            job, _ = worker.receive("job", timeout_s=10.0)
            for attempt, delay_s in ((1, 1.0), (2, 2.0)):
                assert job["attempt"] == attempt
                worker.send({"v": 2, "type": "failed", "job_id": job["job_id"],
                             "attempt": attempt, "reason": "fetch broke", "retryable": True})
                worker.send({"v": 2, "type": "ready", "worker": "flaky"})
                with pytest.raises(AssertionError, match="no 'job' message"):
                    worker.receive("job", timeout_s=0.7 * delay_s)
                job, _ = worker.receive("job", timeout_s=delay_s + 5.0)
            worker.send({"v": 2, "type": "failed", "job_id": job["job_id"], "attempt": 3,
                         "reason": "fetch broke", "retryable": True})
            with running.client() as client:
                deadline = time.monotonic() + 10.0
                while client.status().calibration.failed != 1:
                    assert time.monotonic() < deadline, "the job was not given up"
                    time.sleep(0.05)
        finally:
            worker.close()
    finally:
        running.stop()
    record = json.loads(next((tmp_path / "sessions.outbox").glob("*.final.json")).read_text())
    assert record["state"] == "failed" and "gave up after 3 attempts" in record["reason"]


def test_a_results_report_is_stored_beside_it_only_as_announced(daemon: ThreadDaemon) -> None:
    """The report's files come after the result, each announced by a plain .md/.png name and
    its checksum: a path, another kind of file, a damaged or an unannounced frame are
    refused (and nothing stored); what arrives whole is stored beside result.json."""
    with daemon.client() as client:
        session = Path(client.request("session.start", poses=1)["session"]["path"])
        capture_all(client)
        wait_state(client, "idle")
    result = json.dumps(_result(session)).encode()
    figure, text = b"\x89PNG not really", b"# report\n"

    def done(job: dict, report: list[tuple[str, bytes]], *frames: bytes) -> dict:
        worker.send({"v": 2, "type": "done", "job_id": job["job_id"], "attempt": job["attempt"],
                     "result_sha256": hashlib.sha256(result).hexdigest(),
                     "report": [{"name": n, "sha256": hashlib.sha256(d).hexdigest()}
                                for n, d in report]}, result, *frames)
        return worker.receive("ack")[0]

    calibration = session / "calibration"
    worker = _jobs(daemon)
    try:
        worker.send({"v": 2, "type": "ready", "worker": "rogue"})
        job, _ = worker.receive("job")
        for name in ("../escape.png", "page.html", "result.json", "a/b.png"):
            worker.send({"v": 2, "type": "done", "job_id": job["job_id"],
                         "attempt": job["attempt"],
                         "result_sha256": hashlib.sha256(result).hexdigest(),
                         "report": [{"name": name, "sha256": "0" * 64}]}, result, figure)
            refused, _ = worker.receive("refused")
            assert "report" in refused["reason"], (name, refused)
        for report, frames, why in (([("geometry.png", figure)], (text,), "checksum"),
                                    ([("geometry.png", figure)], (), "1 announced"),
                                    ([], (figure,), "0 announced")):
            ack = done(job, report, *frames)
            assert not ack["accepted"] and why in ack["reason"], ack
            assert not calibration.exists() or not any(calibration.iterdir())
            job, _ = worker.receive("job")  # requeued
        ack = done(job, [("report.md", text), ("geometry.png", figure)], text, figure)
        assert ack["accepted"], ack
    finally:
        worker.close()
    assert (calibration / "report.md").read_bytes() == text
    assert (calibration / "geometry.png").read_bytes() == figure
    assert (calibration / "result.json").read_bytes() == result
