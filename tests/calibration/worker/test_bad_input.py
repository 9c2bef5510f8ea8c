"""A worker against a scripted daemon: malformed jobs, a file whose bytes do not match the
journal, a session that cannot be calibrated. Each gets a clear answer, and the worker goes on
to calibrate a good job afterwards."""

from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TypeVar

import pytest
import zmq

from acquisition.daemon.files import FileServer
from acquisition.contracts.job_messages import (
    WORKER_MESSAGE,
    Done,
    Failed,
    Job,
    JournalPrefix,
    Ready,
    WorkerError,
    encode,
)
from acquisition.daemon.jobs import job_for_session
from acquisition.daemon.outbox import JobRecord
from calibration.worker import Worker, WorkerSettings

WAIT_S = 60.0
Message = TypeVar("Message")


@pytest.fixture
def session(small_session: Path) -> Path:
    return small_session


class ScriptedDaemon:
    """The daemon's two ROUTER sockets, driven by the test; files served by the real server."""

    def __init__(self, root: Path) -> None:
        self.context = zmq.Context()
        self.jobs = self.context.socket(zmq.ROUTER)
        self.jobs.bind(f"ipc://{root}/jobs")
        self.records: dict[str, JobRecord] = {}
        files = self.context.socket(zmq.ROUTER)
        files.bind(f"ipc://{root}/files")
        self.files = FileServer(files, self.records.get)
        self.worker: bytes | None = None

    def receive(self, kind: type[Message]) -> tuple[Message, list[bytes]]:
        """The next worker message of `kind` (heartbeats and progress skipped), serving file
        requests meanwhile. Bounded in time and count."""
        deadline = time.monotonic() + WAIT_S
        poller = zmq.Poller()
        poller.register(self.jobs, zmq.POLLIN)
        poller.register(self.files.sock, zmq.POLLIN)
        for _ in range(100_000):
            left = deadline - time.monotonic()
            assert left > 0, f"no {kind.__name__} from the worker within {WAIT_S} s"
            ready = dict(poller.poll(round(left * 1000)))
            if self.files.sock in ready:
                self.files.serve()
            if self.jobs in ready:
                self.worker, *frames = self.jobs.recv_multipart()
                message = WORKER_MESSAGE.validate_json(frames[0])
                if isinstance(message, kind):
                    return message, frames
        raise AssertionError("too many messages")

    def send(self, payload: bytes) -> None:
        assert self.worker is not None
        self.jobs.send_multipart([self.worker, payload])

    def offer(self, record: JobRecord) -> None:
        self.records[record.job_id] = record
        self.send(encode(Job(job_id=record.job_id, attempt=1, kind=record.kind,
                             session_id=record.session_id, poses=record.poses,
                             journal=record.journal, files=record.files)))

    def close(self) -> None:
        self.jobs.close(0)
        self.files.sock.close(0)
        self.context.term()


@pytest.fixture
def daemon(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[ScriptedDaemon]:
    """A worker and the scripted daemon it talks to; `indirect` parametrisation sets the
    worker's daemon_timeout_s (default 10 s)."""
    scripted = ScriptedDaemon(tmp_path)
    worker = Worker(WorkerSettings(jobs=f"ipc://{tmp_path}/jobs", files=f"ipc://{tmp_path}/files",
                                   name="w", cache=tmp_path / "cache", heartbeat_interval_s=0.1,
                                   joint=False,
                                   daemon_timeout_s=getattr(request, "param", 10.0)))
    thread = threading.Thread(target=worker.run, daemon=True)
    thread.start()
    try:
        scripted.receive(Ready)
        yield scripted
    finally:
        worker.stop()
        thread.join(WAIT_S)
        assert not thread.is_alive()
        scripted.close()


def _renamed(record: JobRecord, suffix: str, **changes: object) -> JobRecord:
    return record.model_copy(update={"job_id": f"{record.job_id}-{suffix}", **changes})


def test_bad_jobs_get_clear_errors_and_the_worker_keeps_serving(
        daemon: ScriptedDaemon, session: Path) -> None:
    daemon.send(b"\xff not json")
    error, _ = daemon.receive(WorkerError)
    assert "malformed message from the daemon" in error.reason

    daemon.send(json.dumps({"v": 2, "type": "job", "job_id": "x.final", "attempt": 1}).encode())
    failed, _ = daemon.receive(Failed)
    assert failed.job_id == "x.final" and not failed.retryable
    assert "malformed" in failed.reason and "files" in failed.reason

    good = job_for_session(session, "final")
    first = good.files[0]
    wrong = first.model_copy(update={"sha256": "0" * 64})
    daemon.offer(_renamed(good, "mismatch", files=[wrong, *good.files[1:]]))
    failed, _ = daemon.receive(Failed)
    assert "checksum mismatch" in failed.reason and first.path in failed.reason
    assert not failed.retryable

    journal = (session / "journal.jsonl").read_bytes()
    cut = journal.index(b'"step_begin"', journal.index(b'"refmic"'))
    cut = journal.rindex(b"\n", 0, cut) + 1  # the journal before the first pose began
    early = JournalPrefix(bytes=cut, sha256=hashlib.sha256(journal[:cut]).hexdigest())
    daemon.offer(_renamed(good, "early", journal=early))
    failed, _ = daemon.receive(Failed)
    assert "cannot be calibrated" in failed.reason and not failed.retryable

    daemon.offer(good)
    done, frames = daemon.receive(Done)
    assert done.job_id == good.job_id
    assert hashlib.sha256(frames[1]).hexdigest() == done.result_sha256
    assert len(json.loads(frames[1])["microphones"]) == 48


def test_a_bug_in_the_calibration_is_retryable_with_its_traceback_in_the_log(
        daemon: ScriptedDaemon, session: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    from tests.micam.test_bugs_are_bugs import BROADCAST_BUG, inject_solver_bug

    inject_solver_bug(monkeypatch)
    caplog.set_level(logging.ERROR, logger="micam.worker")
    daemon.offer(job_for_session(session, "final"))
    failed, _ = daemon.receive(Failed)
    assert failed.retryable, failed.reason
    assert "internal error" in failed.reason and BROADCAST_BUG in failed.reason
    tracebacks = [logging.Formatter().formatException(r.exc_info) for r in caplog.records
                  if r.exc_info is not None]
    assert any("broken_solve" in text and BROADCAST_BUG in text for text in tracebacks), \
        "the bug's traceback is not in the worker's log"


def test_a_job_that_would_leave_the_cache_is_refused(daemon: ScriptedDaemon, session: Path,
                                                     tmp_path: Path) -> None:
    """A rogue daemon's job for session ".." must not make the worker write beside its cache."""
    good = job_for_session(session, "final")
    for session_id in ("..", ".", "a/../..", ""):
        offer = json.loads(encode(Job(job_id=good.job_id, attempt=1, kind="final",
                                      session_id=good.session_id, poses=good.poses,
                                      journal=good.journal, files=good.files)))
        offer["session_id"] = session_id
        daemon.send(json.dumps(offer).encode())
        failed, _ = daemon.receive(Failed)
        assert not failed.retryable and "session_id" in failed.reason
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "files", "jobs"]


def test_daemon_messages_of_another_version_or_none_are_refused(daemon: ScriptedDaemon) -> None:
    for message, words in (({"type": "heartbeat"}, "no protocol version"),
                           ({"v": 3, "type": "heartbeat"}, "version 3 is not supported")):
        daemon.send(json.dumps(message).encode())
        error, _ = daemon.receive(WorkerError)
        assert words in error.reason


@pytest.mark.parametrize("daemon", [1.0], indirect=True)  # it reconnects after 1 s of silence
@pytest.mark.slow
def test_an_oversized_frame_from_the_daemon_is_dropped_unread(daemon: ScriptedDaemon) -> None:
    """The worker's sockets refuse frames above their limit before reading them (a rogue
    daemon cannot make it buffer gigabytes); it carries on once reconnected."""
    daemon.send(b"\xff" * (32 * 2**20))
    deadline = time.monotonic() + WAIT_S
    answers: list[WorkerError] = []
    while time.monotonic() < deadline and not answers:
        daemon.send(b'{"v": 2, "type": "nonsense"}')  # to its identity, once it is back
        while daemon.jobs.poll(100):
            daemon.worker, *frames = daemon.jobs.recv_multipart()
            message = WORKER_MESSAGE.validate_json(frames[0])
            if isinstance(message, WorkerError):
                answers.append(message)
    assert answers and "nonsense" in answers[0].reason  # the first answer is to the small one
