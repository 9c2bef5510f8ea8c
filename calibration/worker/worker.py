"""The worker loop: ask the daemon for work, do one job at a time, heartbeat throughout.

The main thread owns the jobs socket (a DEALER; ZeroMQ sockets are not thread-safe): it says
`ready`, heartbeats every `heartbeat_interval_s`, receives a job and hands it to a job thread,
and sends on whatever the job thread reports (progress, the live update, the result, the
failure). The job thread fetches the files on its own DEALER to the file endpoint, then
calibrates. So a calibration of minutes never silences the heartbeats, and the daemon can tell
a busy worker from a dead one.

Whatever the daemon sends, the worker keeps serving: a message it cannot read is answered with
an `error` (or a non-retryable `failed` when it names a job), and a job that fails (a file that
does not match its checksum, a session that cannot be calibrated) is answered with `failed` and
a message for a person. If the daemon is silent for `daemon_timeout_s`, the worker drops its
socket and connects afresh with a doubling back-off (Paranoid Pirate); a daemon that answers
`reconnect` (it restarted) gets a new `ready` once the worker is idle.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import queue
import socket
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import zmq
from pydantic import BaseModel, ValidationError

from acquisition.contracts.job_messages import (
    DAEMON_MESSAGE,
    FETCH_WINDOW,
    Ack,
    Bye,
    Done,
    Failed,
    Heartbeat,
    Job,
    Live,
    LiveUpdate,
    Progress,
    Ready,
    Reconnect,
    Refused,
    ReportFile,
    WorkerError,
    encode,
    version_problem,
)
from acquisition.contracts.errors import UserError
from acquisition.contracts.keys import secure_client

from .cache import DEFAULT_MAX_BYTES, ChecksumMismatch, FileCache
from ..pipeline import WorkMemo
from .compute import compute
from .fetch import CHUNK_BYTES, FetchFailed, fetch_job_files

log = logging.getLogger("micam.worker")

MAX_BACKOFF_FACTOR = 32  # the reconnect back-off doubles up to this many heartbeat intervals
MAX_JOB_MESSAGE_BYTES = 16 * 2**20
"""The largest frame the worker takes from the daemon's jobs socket (a job lists its files:
about 150 bytes each); ZeroMQ drops a connection that sends more, before it is read."""
MAX_CHUNK_FRAME_BYTES = CHUNK_BYTES + 2**16  # a chunk's bytes, or its JSON header
FILES_QUEUE = 2 * FETCH_WINDOW
"""Messages queued each way on the file socket: twice the fetches in flight, because ZeroMQ
tells a queue's writer what its reader took only every half queue, so a queue of exactly the
window can seem full (and the daemon's reply is then refused: a 30 s stall)."""
JOBS_QUEUE = 16
"""Messages queued each way on the jobs socket: received (jobs, heartbeats, acks: x
MAX_JOB_MESSAGE_BYTES at most) and unsent (for a daemon that stopped reading; `_send` then
drops the message, as for a daemon that is not connected)."""


@dataclass(frozen=True)
class WorkerSettings:
    """How a worker reaches the daemon and works.

    Attributes:
        jobs: the daemon's jobs endpoint; files: its file endpoint.
        name: shown in the daemon's events and status.
        cache: where fetched session files are kept (one worker per directory).
        cache_max_bytes: the cache's size limit, bytes; beyond it whole sessions are evicted,
            least recently used first, never the one a job is using (default 4 GiB).
        heartbeat_interval_s: how often to heartbeat when there is nothing else to send.
        daemon_timeout_s: a daemon silent this long is presumed gone: reconnect.
        joint: run the joint fit in final jobs (the default calibration).
        fetch_timeout_s: longest wait for one file chunk.
        server_key, client_key: CURVE certificates, for a daemon off this machine.
    """

    jobs: str
    files: str
    name: str = field(default_factory=lambda: f"{socket.gethostname()}-{os.getpid()}")
    cache: Path = Path("~/.cache/micam/worker")
    cache_max_bytes: int = DEFAULT_MAX_BYTES
    heartbeat_interval_s: float = 1.0
    daemon_timeout_s: float = 10.0
    joint: bool = True
    fetch_timeout_s: float = 30.0
    server_key: Path | None = None
    client_key: Path | None = None


class Worker:
    """A calibration worker; `run` serves until `stop` is called (or `max_jobs` are done)."""

    def __init__(self, settings: WorkerSettings) -> None:
        self.settings = settings
        self.cache = FileCache(settings.cache, settings.cache_max_bytes)
        # the detections and delays of the session files this worker has seen (live jobs see
        # the same files again, a pose more each time); its cache verified every one of them
        self.memo = WorkMemo()
        self._context = zmq.Context()
        self._stop = threading.Event()
        self._reports: queue.Queue[BaseModel | tuple[Done, list[bytes]] | None] = queue.Queue()
        self._thread: threading.Thread | None = None
        # a job offered while the last one's thread was still ending (see `_start`)
        self._deferred: Job | None = None
        self._sock: zmq.Socket | None = None
        self._announce = False  # `ready` still to be said (sent once connected and idle)
        self.jobs_done = 0

    def stop(self) -> None:
        """Ask `run` to return (after the job in progress, which it abandons)."""
        self._stop.set()

    def run(self, max_jobs: int | None = None) -> int:
        """Serve jobs until stopped; the number of jobs finished (done or failed)."""
        interval = self.settings.heartbeat_interval_s
        backoff = interval
        self._connect()
        heard = next_beat = time.monotonic()
        try:
            while not self._stop.is_set() and (max_jobs is None or self.jobs_done < max_jobs):
                if self._announce and self._thread is None:
                    self._announce = not self._send(Ready(worker=self.settings.name))
                now = time.monotonic()
                if now >= next_beat:
                    self._send(Heartbeat())
                    next_beat = now + interval
                assert self._sock is not None
                busy = self._thread is not None
                wait_s = min(next_beat - now, 0.05 if busy else interval)
                if self._sock.poll(max(1, round(wait_s * 1000)), zmq.POLLIN):
                    self._receive(self._sock.recv_multipart())
                    heard = time.monotonic()
                    backoff = interval
                self._forward_reports()
                if time.monotonic() - heard > self.settings.daemon_timeout_s:
                    log.warning("no word from the daemon for %g s; reconnecting in %g s",
                                self.settings.daemon_timeout_s, backoff)
                    self._stop.wait(backoff)
                    backoff = min(backoff * 2, interval * MAX_BACKOFF_FACTOR)
                    self._connect()
                    heard = time.monotonic()
        finally:
            self._send(Bye())
            if self._sock is not None:
                self._sock.close(linger=0)
            if self._thread is not None:  # a job in progress is abandoned; it dies with us
                log.warning("stopping with a job in progress; the daemon will give it to "
                            "another worker")
            self._context.destroy(linger=0)
        return self.jobs_done

    # -- the jobs socket ------------------------------------------------------------------------

    def _connect(self) -> None:
        """A fresh DEALER (new identity) to the daemon, announced with `ready` when idle."""
        if self._sock is not None:
            self._sock.close(linger=0)
        sock = self._context.socket(zmq.DEALER)
        sock.linger = 0
        sock.immediate = 1  # queue nothing for a daemon that is not there (no stale flood)
        sock.identity = f"{self.settings.name}-{uuid.uuid4().hex[:8]}".encode()
        sock.maxmsgsize = MAX_JOB_MESSAGE_BYTES  # set before connect, or it never applies
        sock.rcvhwm = sock.sndhwm = JOBS_QUEUE
        self._secure(sock)
        sock.connect(self.settings.jobs)
        self._sock = sock
        self._announce = True

    def _secure(self, sock: zmq.Socket) -> None:
        s = self.settings
        if s.server_key is not None and s.client_key is not None:
            secure_client(sock, s.server_key, s.client_key)

    def _send(self, message: BaseModel, *data: bytes) -> bool:
        """Send now or not at all: with no daemon connected, the message is dropped (a lease
        the daemon no longer sees is given to another worker anyway). True if sent."""
        if self._sock is None:
            return False
        frames = [encode(message), *data]
        try:
            self._sock.send_multipart(frames, zmq.NOBLOCK)
        except zmq.Again:
            log.debug("daemon not connected; dropped a %s message", type(message).__name__)
            return False
        return True

    def _receive(self, frames: list[bytes]) -> None:
        try:
            if len(frames) != 1:
                raise ValueError(f"a daemon message is one frame; got {len(frames)}")
            problem = version_problem(frames[0])
            if problem is not None:
                raise ValueError(problem)
            message = DAEMON_MESSAGE.validate_json(frames[0])
        except (ValidationError, ValueError) as exc:
            self._refuse(frames, exc)
            return
        if isinstance(message, Refused):
            log.error("the daemon refused a message of this worker: %s", message.reason)
        elif isinstance(message, Job):
            self._start(message)
        elif isinstance(message, Reconnect):
            self._announce = True
        elif isinstance(message, Ack) and not message.accepted:
            log.info("the daemon did not count %s attempt %d: %s", message.job_id,
                     message.attempt, message.reason)

    def _refuse(self, frames: list[bytes], exc: Exception) -> None:
        """Answer a message that cannot be read: `failed` if it names a job, else `error`."""
        reason = f"malformed message from the daemon: {_describe(exc)}"
        log.error("%s", reason)
        try:
            raw = json.loads(frames[0])
            job_id, attempt = str(raw["job_id"]), int(raw["attempt"])
            failed = Failed(job_id=job_id, attempt=max(attempt, 1), reason=reason,
                            retryable=False)
        except Exception:
            self._send(WorkerError(reason=reason[:4000]))
            return
        self._send(failed)
        self.jobs_done += 1

    # -- jobs -----------------------------------------------------------------------------------

    def _start(self, job: Job) -> None:
        """Run `job` on a thread of its own; one offered while the last job's thread is still
        ending is run after it.

        Why wait rather than refuse: the daemon counts this worker idle from its last word on
        a job, which the job thread reports a moment before it ends. A refusal (retryable) was
        re-offered at once, and the race repeated until the job's attempts were spent (the
        chaos test's 20 in a row). Only a second offer while one waits is refused."""
        if self._thread is not None:
            if self._deferred is None:
                self._deferred = job
                return
            self._send(Failed(job_id=job.job_id, attempt=job.attempt, retryable=True,
                              reason=f"worker {self.settings.name} is busy with another job"))
            return
        log.info("job %s attempt %d (%s, %d poses)", job.job_id, job.attempt, job.kind, job.poses,
                 extra={"session_id": job.session_id})
        self._thread = threading.Thread(target=self._work, args=(job,), daemon=True,
                                        name=f"job-{job.job_id}")
        self._thread.start()

    def _work(self, job: Job) -> None:
        """The job thread: fetch, calibrate, report (never raises)."""
        report = self._reports.put
        try:
            with self.cache.use(job) as session:  # not evicted while fetched and calibrated
                files = self._context.socket(zmq.DEALER)
                files.linger = 0
                files.maxmsgsize = MAX_CHUNK_FRAME_BYTES
                files.rcvhwm = files.sndhwm = FILES_QUEUE
                self._secure(files)
                files.connect(self.settings.files)
                try:
                    report(Progress(job_id=job.job_id, attempt=job.attempt, stage="fetch"))
                    fetch_job_files(files, job, self.cache,
                                    timeout_s=self.settings.fetch_timeout_s)
                finally:
                    files.close(linger=0)
                out = compute(job, session, self.settings.joint,
                              lambda stage: report(Progress(job_id=job.job_id,
                                                            attempt=job.attempt,
                                                            stage=stage[:64])),
                              self.memo)
            if isinstance(out, LiveUpdate):
                report(Live(job_id=job.job_id, attempt=job.attempt, update=out))
            else:
                announced = [ReportFile(name=name, sha256=hashlib.sha256(data).hexdigest())
                             for name, data in out.report.items()]
                report((Done(job_id=job.job_id, attempt=job.attempt,
                             result_sha256=hashlib.sha256(out.result).hexdigest(),
                             report=announced), [out.result, *out.report.values()]))
        except FetchFailed as exc:
            report(self._failure(job, f"cannot fetch the session: {exc}", exc.retryable))
        except ChecksumMismatch as exc:
            report(self._failure(job, f"checksum mismatch: {exc}", False))
        except UserError as exc:  # the session (or its files) cannot calibrate: for good
            report(self._failure(job, f"the session cannot be calibrated: {exc}", False))
        except Exception as exc:  # a bug or a full disk: another worker may do better
            log.exception("job %s failed", job.job_id, extra={"session_id": job.session_id})
            report(self._failure(job, f"internal error: {type(exc).__name__}: {exc}", True))
        finally:
            report(None)  # the job thread is finished

    def _failure(self, job: Job, reason: str, retryable: bool) -> Failed:
        log.error("job %s failed: %s", job.job_id, reason, extra={"session_id": job.session_id})
        return Failed(job_id=job.job_id, attempt=job.attempt, reason=reason[:4000],
                      retryable=retryable)

    def _forward_reports(self) -> None:
        """Send what the job thread reported; notice when it has finished."""
        for _ in range(1000):
            try:
                report = self._reports.get_nowait()
            except queue.Empty:
                return
            if report is None:
                assert self._thread is not None
                self._thread.join()
                self._thread = None
                self.jobs_done += 1
                if self._deferred is not None:
                    job, self._deferred = self._deferred, None
                    self._start(job)
            elif isinstance(report, tuple):
                self._send(report[0], *report[1])
            else:
                self._send(report)


def _describe(exc: Exception) -> str:
    if isinstance(exc, ValidationError):
        return "; ".join(f"{'.'.join(map(str, e['loc'])) or 'message'}: {e['msg']}"
                         for e in exc.errors()[:5])
    return str(exc)
