"""The job broker: calibration workers, their heartbeats and leases, and what they send back.

A ROUTER socket (ROUTER_MANDATORY, so a message to a vanished worker fails loudly instead of
being dropped) that workers connect to with DEALER sockets, after the zguide's Paranoid Pirate
and Majordomo patterns:

- a worker says `ready`; the broker gives each idle worker at most one job, the oldest pending
  one, and only to workers that asked (never PUSH: jobs queued to a dead worker are lost);
- both sides heartbeat; a worker silent for `liveness` intervals is dead and its job goes back
  to pending; so does a job leased longer than `job_timeout_s`;
- a job that a worker failed with a retryable error waits `retry_delay_s` before it is offered
  again, twice as long after each further attempt (the fault gets time to clear instead of
  every attempt being spent within milliseconds); `max_attempts` leases in all;
- every lease increments the job's `attempt`, and only the current attempt's answer counts
  (fencing): a late answer of a dead or timed-out lease is acknowledged as stale and ignored;
- results are checked against their session (result_check.py: a rogue or broken worker
  cannot replace a calibration with nonsense), then stored once, beside the session
  (calibration/result.json for the final job, after its report: report.md and its PNG
  figures, plain names checked by the message's model, each against its checksum; the latest
  calibration/live.json for live ones), before the job is marked done. If result.json is there already (an earlier attempt
  stored it and the daemon stopped before marking the job done) that file is kept and its own
  checksum recorded, so the outbox always describes the file on disk;
- a message of another protocol version, or with none, is answered with `refused` and why.

Every lease is in the outbox on disk before it is sent; when the outbox's disk refuses writes
the other changes wait in memory and nothing is lost (see outbox.py). Finished records are
pruned after `keep_finished_days`. The broker runs in the daemon's one loop thread: `serve`
reads waiting messages, `tick` does the timed work.
"""

from __future__ import annotations

import hashlib
import json
import logging
import posixpath
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Any

import zmq
from pydantic import BaseModel, ValidationError

from acquisition.contracts.session import SessionError
from acquisition.contracts.session import fsync_dir, partial_path, sha256_file, write_atomic
from acquisition.contracts.session._layout import attempt_of_dir
from acquisition.contracts.step_ids import is_pose_step
from .config import WorkersConfig
from acquisition.contracts.job_messages import (
    WORKER_MESSAGE,
    Ack,
    Bye,
    Done,
    Failed,
    Heartbeat,
    Job,
    Live,
    Progress,
    Ready,
    Reconnect,
    Refused,
    WorkerError,
    encode,
    version_problem,
)
from .outbox import JobRecord, Outbox
from acquisition.contracts.protocol import (
    CalibrationEvent,
    CalibrationStatus,
    ErrorEvent,
    JobEvent,
    LiveCalibrationEvent,
    WorkerEvent,
    WorkerSummary,
    utc_now,
)
from .result_check import ResultRejected, SessionFacts, check_live, check_result, parse_result

log = logging.getLogger("micam.daemon")

CALIBRATION_DIR = "calibration"
RESULT_FILE = "result.json"
LIVE_FILE = "live.json"
LIVE_HISTORY_FILE = "live_history.jsonl"
"""One line per live update (poses, predicted accuracy, mean uncertainty, c): how the live
calibration improved, for a page drawing it against poses. Derived data, appended unsynced."""
MAX_MESSAGES_PER_TURN = 100
FLUSH_INTERVAL_S = 1.0  # how often records kept in memory are offered to the disk again
PRUNE_INTERVAL_S = 3600.0
JOBS_QUEUE = 16
"""Messages queued per worker connection on the jobs socket, each way: received (x
`max_result_bytes`: their memory bound; a worker sends a handful between two turns of the
loop) and unsent (heartbeats, acks and offers of a few kilobytes, for a worker that stopped
reading; the broker's sends then fail with `zmq.Again` and are logged)."""

Publish = Callable[..., Any]


@dataclass
class _Worker:
    """A connected worker as the broker sees it."""

    identity: bytes
    name: str
    last_seen: float
    job: str | None = None  # the job it works on (maybe taken back since: then its answer is stale)
    idle_since: float = field(default_factory=time.monotonic)


class Broker:
    """Hands the outbox's jobs to workers on `sock` (a bound ROUTER); see the module docstring."""

    def __init__(self, sock: zmq.Socket, config: WorkersConfig, outbox: Outbox,
                 publish: Publish) -> None:
        self.sock = sock
        sock.router_mandatory = 1
        self.config = config
        self.outbox = outbox
        self._publish = publish
        self.workers: dict[bytes, _Worker] = {}
        self._next_heartbeat = 0.0
        self._next_flush = 0.0
        self._next_prune = 0.0
        self._outbox_failing = False
        self._facts: dict[str, SessionFacts] = {}  # by session path, read on first need

    @property
    def silence_s(self) -> float:
        """A worker silent this long is dead."""
        return self.config.heartbeat_interval_s * self.config.liveness

    # -- jobs in --------------------------------------------------------------------------------

    def submit(self, job: JobRecord) -> None:
        """Queue `job` unless the outbox has it already; a newer job of a session supersedes
        its pending live jobs (their poses are in the newer one)."""
        if job.job_id in self.outbox.jobs:
            return
        for old in list(self.outbox.jobs.values()):
            if (old.session_id == job.session_id and old.kind == "live"
                    and old.state == "pending"):
                self.outbox.remove(old)
                self._job_event(old, "superseded", reason=f"by {job.job_id}")
        self.outbox.add(job)
        self._job_event(job, "queued")
        self._check_outbox()
        self._dispatch()

    def status(self) -> CalibrationStatus:
        states = [j.state for j in self.outbox.jobs.values()]
        return CalibrationStatus(
            workers=[WorkerSummary(name=w.name, job=w.job) for w in self.workers.values()],
            pending=states.count("pending"), leased=states.count("leased"),
            done=states.count("done"), failed=states.count("failed"))

    # -- the loop -----------------------------------------------------------------------------

    def serve(self) -> None:
        """Handle the messages waiting (bounded per turn), then hand out jobs."""
        for _ in range(MAX_MESSAGES_PER_TURN):
            try:
                identity, *frames = self.sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            try:
                self._handle(identity, frames)
            except Exception:  # a bug: log it, keep brokering
                log.exception("internal error while handling a worker message")
        self._dispatch()

    def tick(self) -> None:
        """Timed work: declare silent workers dead, take back overdue leases, heartbeat."""
        now = time.monotonic()
        for worker in [w for w in self.workers.values() if now - w.last_seen > self.silence_s]:
            self._lose(worker, f"silent for more than {self.silence_s:g} s")
        overdue = time.time() - self.config.job_timeout_s
        for job in [j for j in self.outbox.jobs.values()
                    if j.state == "leased" and j.updated_utc.timestamp() < overdue]:
            self._requeue(job, f"attempt {job.attempt} took longer than "
                               f"{self.config.job_timeout_s:g} s")
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + self.config.heartbeat_interval_s
            for worker in list(self.workers.values()):
                self._send(worker, Heartbeat())
        if self.outbox.unsaved and now >= self._next_flush:
            self._next_flush = now + FLUSH_INTERVAL_S
            self.outbox.flush()
            self._check_outbox()
        if now >= self._next_prune:
            self._next_prune = now + PRUNE_INTERVAL_S
            self.prune()
        self._dispatch()

    def prune(self) -> None:
        """Forget the records of jobs finished more than `keep_finished_days` ago."""
        cutoff = utc_now() - timedelta(days=self.config.keep_finished_days)
        for job_id in self.outbox.prune(cutoff):
            log.info("pruned the finished job %s from the outbox", job_id)

    def _check_outbox(self) -> None:
        """Tell the operator once when the outbox's disk starts or stops refusing writes."""
        failing = bool(self.outbox.unsaved)
        if failing and not self._outbox_failing:
            self._publish(ErrorEvent, message=f"the outbox {self.outbox.directory} refuses "
                          "writes (disk full or read-only?); calibration jobs are kept in memory "
                          "and written, then offered to workers, once it takes writes again")
        elif self._outbox_failing and not failing:
            log.info("the outbox takes writes again")
        self._outbox_failing = failing

    def close(self) -> None:
        self.sock.close(linger=0)

    # -- messages -----------------------------------------------------------------------------

    def _handle(self, identity: bytes, frames: list[bytes]) -> None:
        worker = self.workers.get(identity)
        if worker is not None:
            worker.last_seen = time.monotonic()
        problem = version_problem(frames[0]) if frames else "an empty message"
        message = None
        if problem is None:
            try:
                message = WORKER_MESSAGE.validate_json(frames[0])
            except ValidationError as exc:
                problem = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'message'}: {e['msg']}"
                                    for e in exc.errors()[:3])
        if message is None:
            log.warning("refused a message from a worker: %s", problem)
            self._send_raw(identity, Refused(reason=f"unreadable message: {problem}"))
            return
        if isinstance(message, Ready):
            self._ready(identity, worker, message)
        elif worker is None:
            # Unknown: the daemon restarted or declared it dead. Its answers are stale (every
            # lease it held was taken back), but acknowledge them so it does not wait.
            if isinstance(message, Done | Failed | Live):
                self._send_raw(identity, Ack(job_id=message.job_id, attempt=message.attempt,
                                            accepted=False, reason="the daemon does not know "
                                            "this worker; its lease was taken back"))
            if not isinstance(message, Bye):
                self._send_raw(identity, Reconnect(reason="unknown worker; say ready"))
        elif isinstance(message, Heartbeat):
            pass
        elif isinstance(message, Progress):
            job = self._fenced(worker, message.job_id, message.attempt)
            if job is not None:
                self._job_event(job, "running", worker=worker.name, reason=message.stage)
        elif isinstance(message, Live):
            self._finish(worker, message.job_id, message.attempt,
                         lambda job: self._store_live(job, worker, message))
        elif isinstance(message, Done):
            result = frames[1] if len(frames) >= 2 else b""
            self._finish(worker, message.job_id, message.attempt,
                         lambda job: self._store_result(job, worker, message, result,
                                                        frames[2:]))
        elif isinstance(message, Failed):
            self._finish(worker, message.job_id, message.attempt,
                         lambda job: self._failed(job, worker, message))
        elif isinstance(message, WorkerError):
            self._publish(ErrorEvent, message=f"calibration worker {worker.name}: "
                                              f"{message.reason}")
        elif isinstance(message, Bye):
            self._lose(worker, "it stopped", state="left")

    def _ready(self, identity: bytes, worker: _Worker | None, message: Ready) -> None:
        if worker is None:
            self.workers[identity] = _Worker(identity, message.worker, time.monotonic())
            self._publish(WorkerEvent, worker=message.worker, state="joined")
            log.info("worker %s joined", message.worker)
        elif worker.job is not None:  # it restarted its work: whatever it held is lost
            job = self.outbox.jobs.get(worker.job)
            worker.job = None
            worker.idle_since = time.monotonic()
            if job is not None and job.state == "leased" and job.worker == worker.name:
                self._requeue(job, f"worker {worker.name} said ready while holding it")

    def _fenced(self, worker: _Worker, job_id: str, attempt: int) -> JobRecord | None:
        """The job if `attempt` is its current lease, held by `worker`; else None (stale)."""
        job = self.outbox.jobs.get(job_id)
        if (job is None or job.state != "leased" or job.attempt != attempt
                or job.worker != worker.name or worker.job != job_id):
            return None
        return job

    def _finish(self, worker: _Worker, job_id: str, attempt: int,
                apply: Callable[[JobRecord], str]) -> None:
        """A worker's last word on a job: `apply` it if the lease is current, acknowledge."""
        job = self._fenced(worker, job_id, attempt)
        if worker.job == job_id:
            worker.job = None
            worker.idle_since = time.monotonic()
        if job is None:
            current = self.outbox.jobs.get(job_id)
            why = (f"stale: the job is {current.state} at attempt {current.attempt}"
                   if current is not None else "no such job")
            self._send(worker, Ack(job_id=job_id, attempt=attempt, accepted=False, reason=why))
            return
        try:
            reason = apply(job)
        except Exception as exc:  # a full disk, a bug: the job is not done; try again later
            log.exception("cannot store the answer to %s", job_id)
            self._requeue(job, f"the daemon could not store the answer: {exc}")
            reason = f"not stored: {exc}"
        self._send(worker, Ack(job_id=job_id, attempt=attempt, accepted=not reason,
                               reason=reason))

    def _store_live(self, job: JobRecord, worker: _Worker, message: Live) -> str:
        try:
            check_live(message.update, self._session_facts(job))
        except ResultRejected as exc:
            self._requeue(job, f"worker {worker.name} sent a live update that does not describe "
                               f"the session: {exc}")
            return f"rejected: {exc}"
        update = message.update
        directory = _calibration_dir(job)
        _replace(directory / LIVE_FILE, update.model_dump_json(indent=1).encode())
        with (directory / LIVE_HISTORY_FILE).open("a") as history:
            history.write(json.dumps({
                "poses": update.poses, "predicted_accuracy_m": update.predicted_accuracy_m,
                "mean_uncertainty_m": update.mean_uncertainty_m,
                "speed_of_sound_m_s": update.speed_of_sound_m_s}) + "\n")
        self._publish(LiveCalibrationEvent, session_id=job.session_id, job_id=job.job_id,
                      update=message.update)
        self._job_event(job, "done", worker=worker.name)
        self.outbox.remove(job)
        return ""

    def _store_result(self, job: JobRecord, worker: _Worker, message: Done,
                      result: bytes, report: list[bytes]) -> str:
        digest = hashlib.sha256(result).hexdigest()
        if digest != message.result_sha256:
            self._requeue(job, f"the result from {worker.name} arrived damaged (sha256 "
                               f"{digest}, announced {message.result_sha256})")
            return "result checksum mismatch"
        damaged = _damaged_report(message, report)
        if damaged:
            self._requeue(job, f"the report from {worker.name} arrived damaged: {damaged}")
            return f"report damaged: {damaged}"
        try:
            check_result(parse_result(result), self._session_facts(job))
        except ResultRejected as exc:
            self._requeue(job, f"worker {worker.name} sent a result that does not describe the "
                               f"session: {exc}")
            return f"rejected: {exc}"
        for file, data in zip(message.report, report, strict=True):  # before the result, which
            _store_once(_calibration_dir(job) / file.name, data)   # says the report is there
        path = _calibration_dir(job) / RESULT_FILE
        partial_path(path).unlink(missing_ok=True)  # a crash mid-write; this is its one writer
        try:
            write_atomic(path, lambda fh: fh.write(result))
        except SessionError:  # stored by an earlier attempt whose ack was lost: keep that one
            log.warning("%s already exists; keeping it", path)
            result = path.read_bytes()
            digest = sha256_file(path).sha256
        summary = _summarize(parse_result(result))
        job = self.outbox.record(job, state="done", result_sha256=digest, reason="")
        self._check_outbox()
        self._job_event(job, "done", worker=worker.name)
        self._publish(CalibrationEvent, session_id=job.session_id, job_id=job.job_id,
                      attempt=job.attempt, worker=worker.name, path=str(path), sha256=digest,
                      **summary)
        return ""

    def _session_facts(self, job: JobRecord) -> SessionFacts:
        """What the job's answers must agree with (read once per session; ResultRejected if
        the session cannot be read)."""
        facts = self._facts.get(job.session_path)
        if facts is None or not _pose_steps(job) <= facts.poses:  # new poses since: read again
            facts = self._facts[job.session_path] = SessionFacts.read(Path(job.session_path))
        return facts

    def _failed(self, job: JobRecord, worker: _Worker, message: Failed) -> str:
        reason = f"on worker {worker.name}: {message.reason}"
        if message.retryable:
            # a transient fault (a broken fetch, a busy worker) needs time to clear: offered
            # again at once, every attempt would be spent within milliseconds
            self._requeue(job, reason, self.config.retry_delay_s * 2.0 ** (job.attempt - 1))
        else:
            self._give_up(job, reason)
        return ""

    # -- leases -------------------------------------------------------------------------------

    def _dispatch(self) -> None:
        """Give the oldest pending jobs to the longest-idle workers, one job per worker."""
        idle = sorted((w for w in self.workers.values() if w.job is None),
                      key=lambda w: w.idle_since)
        now = utc_now()
        # a job file's wait is believed up to the longest one this broker sets (an edited or
        # clock-skewed record must not hold a job back for ever)
        longest = timedelta(seconds=self.config.retry_delay_s
                            * 2.0 ** (self.config.max_attempts - 1))
        ready = [j for j in self.outbox.pending()
                 if j.not_before_utc is None or j.not_before_utc <= now
                 or j.not_before_utc > now + longest]
        for job, worker in zip(ready, idle, strict=False):
            try:
                offer = Job(job_id=job.job_id, attempt=job.attempt + 1, kind=job.kind,
                            session_id=job.session_id, poses=job.poses, journal=job.journal,
                            files=job.files)
            except ValidationError as exc:  # outbox records are validated; never seen
                self._give_up(job, f"the job cannot be offered: {exc}")
                continue
            try:
                job = self.outbox.update(job, state="leased", attempt=offer.attempt,
                                         worker=worker.name, reason="", not_before_utc=None)
            except OSError as exc:  # a lease is sent only once it is on disk
                log.error("cannot lease %s: %s; trying again later", job.job_id, exc)
                self.outbox.unsaved.add(job.job_id)  # flush retries, then leases follow
                self._check_outbox()
                return
            worker.job = job.job_id
            if self._send(worker, offer):
                self._job_event(job, "leased", worker=worker.name)

    def _requeue(self, job: JobRecord, reason: str, delay_s: float = 0.0) -> None:
        """Take a job back; pending again (offered after `delay_s` seconds), or failed once
        `max_attempts` leases are spent."""
        if job.attempt >= self.config.max_attempts:
            self._give_up(job, f"{reason}; gave up after {job.attempt} attempts")
            return
        not_before = None
        if delay_s > 0:
            not_before = utc_now() + timedelta(seconds=delay_s)
            reason = f"{reason}; offered again in {delay_s:g} s"
        job = self.outbox.record(job, state="pending", worker=None, reason=reason,
                                 not_before_utc=not_before)
        self._check_outbox()
        self._job_event(job, "requeued", reason=reason)

    def _give_up(self, job: JobRecord, reason: str) -> None:
        job = self.outbox.record(job, state="failed", worker=None, reason=reason)
        self._check_outbox()
        self._job_event(job, "failed", reason=reason)
        log.error("calibration job %s failed: %s", job.job_id, reason)
        if job.kind == "live":
            self.outbox.remove(job)

    def _lose(self, worker: _Worker, why: str, state: str = "lost") -> None:
        """Forget a worker; its job goes back to pending."""
        self.workers.pop(worker.identity, None)
        self._publish(WorkerEvent, worker=worker.name, state=state, reason=why)
        log.warning("worker %s %s: %s", worker.name, state, why)
        job = self.outbox.jobs.get(worker.job) if worker.job else None
        if job is not None and job.state == "leased" and job.worker == worker.name:
            self._requeue(job, f"worker {worker.name} {state} ({why})")

    # -- sending ------------------------------------------------------------------------------

    def _send(self, worker: _Worker, message: BaseModel) -> bool:
        """Send to a known worker; a vanished one (EHOSTUNREACH) is lost. True if sent."""
        try:
            self.sock.send_multipart([worker.identity, encode(message)], zmq.NOBLOCK)
        except zmq.ZMQError as exc:
            self._lose(worker, f"unreachable ({exc})")
            return False
        return True

    def _send_raw(self, identity: bytes, message: BaseModel) -> None:
        try:
            self.sock.send_multipart([identity, encode(message)], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass  # it went away again: nothing to tell it

    def _job_event(self, job: JobRecord, state: str, worker: str | None = None,
                   reason: str = "") -> None:
        self._publish(JobEvent, session_id=job.session_id, job_id=job.job_id, kind=job.kind,
                      state=state, attempt=job.attempt, worker=worker or job.worker,
                      reason=reason)


def _calibration_dir(job: JobRecord) -> Path:
    """The session's calibration directory (made durable on first use)."""
    directory = Path(job.session_path) / CALIBRATION_DIR
    if not directory.is_dir():
        directory.mkdir()
        fsync_dir(directory.parent)
    return directory


def _damaged_report(message: Done, report: list[bytes]) -> str:
    """What is wrong with the report files that came with `message` ('' if nothing): one
    frame per announced file, each with its announced checksum."""
    if len(report) != len(message.report):
        return f"{len(report)} files sent, {len(message.report)} announced"
    for file, data in zip(message.report, report, strict=True):
        if hashlib.sha256(data).hexdigest() != file.sha256:
            return f"{file.name}: checksum mismatch"
    return ""


def _store_once(path: Path, data: bytes) -> None:
    """Write `path` once (a file an earlier attempt stored is kept)."""
    partial_path(path).unlink(missing_ok=True)
    try:
        write_atomic(path, lambda fh: fh.write(data))
    except SessionError:
        log.warning("%s already exists; keeping it", path)


def _replace(path: Path, data: bytes) -> None:
    """Write `path` atomically over its previous content (this process is its only writer)."""
    write_atomic(path, lambda fh: fh.write(data), replace=True)


def _pose_steps(job: JobRecord) -> set[str]:
    """The pose steps a job's files belong to ("poses/0003-a1/..." -> "pose/0003")."""
    steps = set()
    for file in job.files:
        attempt = attempt_of_dir(posixpath.dirname(file.path))
        if attempt is not None and is_pose_step(attempt[0]):
            steps.add(attempt[0])
    return steps


def _summarize(result: dict) -> dict[str, Any]:
    """The figures a `calibration` event carries, from a result.json document."""
    stds = [sum(s * s for s in m["std_m"]) ** 0.5 for m in result["microphones"]]
    return {"n_microphones": len(stds), "mean_std_m": sum(stds) / max(len(stds), 1),
            "speed_of_sound_m_s": float(result["speed_of_sound_m_s"])}
