"""The daemon: one thread that serves the sockets, drives the capture and pings the watchdog.

There is no second thread to race with: while a session waits for the operator, the run's
`perform` serves the sockets; while a step is captured, the sockets are served between files.
So a request is answered within one burst, and a wedged hardware call stops the watchdog
pings, as systemd's watchdog intends. (The session index reads journals on a thread of its
own, which waits while a step is captured; see index.py.)

The loop never dies of what it serves: each part of a turn (the sockets, the broker, the
hands-free look) runs inside a guard that logs a bug and carries on. SIGTERM abandons the step
in progress after its current burst and leaves the session interrupted, exactly as a crash
would but tidier; at the next start the daemon offers the session for resuming or, with
`resume_at_start = "auto"`, resumes it.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zmq
from pydantic import BaseModel, ValidationError

from acquisition.contracts.protocol import ErrorEvent, Request, SessionStartArgs, StateEvent
from acquisition.contracts.session import SessionError, SessionReader
from acquisition.contracts.step_ids import is_pose_step

from ..live.mode import POLL_S as LIVE_POLL_S
from . import handlers
from .broker import CALIBRATION_DIR, JOBS_QUEUE, RESULT_FILE, Broker
from .config import DaemonConfig
from .files import CHUNK_QUEUE, FETCH_QUEUE, MAX_FETCH_BYTES, FileServer
from .hardware import Hardware
from .index import SessionIndex
from .jobs import job_for_session
from .live_control import LiveControl
from .outbox import Outbox
from .previews import Previews
from .run import SessionEnding, SessionRun
from .server import ControlServer, Refusal
from .states import State, StateMachine, Transition, WrongState, check_allowed
from .systemd import Watchdog, sd_notify, set_log_context
from .translog import TransitionLog

log = logging.getLogger("micam.daemon")

SIGTERM_REASON = "the daemon was stopped (SIGTERM)"
RECONCILE_LIMIT = 20
"""At start-up, the newest complete sessions without a calibration or a job get their final
job again (a full outbox lost it before a restart); at most this many, so that a root of
sessions copied in does not flood the workers or hold up the loop."""


class Daemon:
    """Serves the control protocol on `hardware` until told to terminate."""

    def __init__(self, config: DaemonConfig, hardware: Hardware) -> None:
        self.config = config
        self.hardware = hardware
        self.session_root = config.session_root.expanduser()
        self.session_root.mkdir(parents=True, exist_ok=True)
        self.machine = StateMachine(self._on_transition)
        self.watchdog = Watchdog()
        self.run: SessionRun | None = None
        self.terminating = False
        self.translog: TransitionLog | None = None
        self._reconciled = False
        self._handlers: dict[str, Callable[[Any], BaseModel | dict[str, Any]]] = {
            command: functools.partial(handler, self)
            for command, handler in handlers.HANDLERS.items()}
        rig = hardware.config.rig
        self.previews: Previews = Previews(config.previews, hardware.cameras,
                                           (rig.corners_x, rig.corners_y), self.publish,
                                           config.camera_timeout_s)
        self.index = SessionIndex(self.session_root,
                                  busy=lambda: self.machine.state is State.CAPTURING)
        self.server = ControlServer(config.sockets, self._handle)
        self.live: LiveControl = LiveControl(hardware, self.machine, self.session_root,
                                             self.publish, self.server.publish_frames,
                                             config.camera_timeout_s)
        try:
            self.broker, self.files = self._open_broker()
        except BaseException:
            self.server.close()
            raise
        self.index.start()

    def _open_broker(self) -> tuple[Broker, FileServer]:
        """The calibration hand-off: the outbox, the jobs socket and the file server."""
        workers = self.config.workers
        default = self.session_root.with_name(self.session_root.name + ".outbox")
        outbox = Outbox((workers.outbox or default).expanduser(), self.session_root)
        requeued = outbox.load()
        sockets = self.config.sockets
        broker = Broker(self.server.bind(zmq.ROUTER, sockets.jobs_endpoint,
                                         sockets.max_result_bytes, JOBS_QUEUE, JOBS_QUEUE),
                        workers, outbox, self.publish)
        files = FileServer(self.server.bind(zmq.ROUTER, sockets.files_endpoint, MAX_FETCH_BYTES,
                                            FETCH_QUEUE, CHUNK_QUEUE), outbox.jobs.get)
        self.server.watch(broker.sock, broker.serve)
        self.server.watch(files.sock, files.serve)
        for job in requeued:
            log.warning("calibration job %s was leased when the daemon stopped; pending again",
                        job.job_id)
        return broker, files

    # -- the loop ---------------------------------------------------------------------------

    def serve_forever(self) -> None:
        """Serve until `terminate` was called and any open session is closed."""
        sd_notify("READY=1", f"STATUS=idle; sessions in {self.session_root}")
        log.info("ready: control %s, events %s, sessions in %s", self.config.sockets.control,
                 self.server.events_endpoint, self.session_root)
        try:
            while True:
                run = self.run
                if run is not None and run.ready():
                    self._advance(run)
                elif self.terminating and run is None:
                    self.live.stop(SIGTERM_REASON)
                    break
                else:
                    self.service(self.config.poll_interval_s if self.live.mode is None
                                 else min(LIVE_POLL_S, self.config.poll_interval_s))
        finally:
            sd_notify("STOPPING=1")
            if self.run is not None:  # only on a second signal: left resumable
                self.run.writer.close()
            self.index.close()
            self.broker.close()
            self.files.sock.close(linger=0)
            self.server.close()
            self.hardware.close()
            log.info("stopped")

    def service(self, timeout_s: float) -> None:
        """One turn of the loop: watchdog, requests (waiting up to `timeout_s`), the broker's
        timed work, hands-free, and what the start-up left to do. Never raises (a bug is
        logged and the loop carries on), so a capture is never interrupted by it."""
        self.watchdog.tick()
        run = self.run
        if self.terminating and run is not None and (run.ending is None
                                                     or not run.ending.after_burst):
            run.ending = SessionEnding("interrupted", SIGTERM_REASON, after_burst=True)
        if not _guarded("serving the sockets", self.server.serve, timeout_s):
            time.sleep(timeout_s)  # no busy loop on a persistent bug
        _guarded("the broker's timed work", self.broker.tick)
        if self.run is not None:
            _guarded("hands-free", self.run.hands_free_tick)
        _guarded("live mode", self.live.tick)
        _guarded("the previews", self.previews.tick,
                 self.machine.state in (State.CAPTURING, State.LIVE))
        if not self._reconciled and self.index.complete:
            self._reconciled = True
            _guarded("the start-up checks", self._after_first_scan)

    def terminate(self) -> None:
        """Ask the daemon to end the current burst, leave any session resumable and exit."""
        self.terminating = True

    def publish(self, event_type: type, **fields: Any) -> None:
        if self.run is not None:
            fields.setdefault("session_id", self.run.session_id)
        self.server.publish(event_type, **fields)

    def _advance(self, run: SessionRun) -> None:
        try:
            closed = run.advance()
        except Exception as exc:  # a full disk, a bug: keep what is recorded, stay up
            log.exception("session %s interrupted", run.session_id)
            run.writer.close()
            self.publish(ErrorEvent, step=run.step,
                         message=f"session interrupted: {type(exc).__name__}: {exc}; fix the "
                                 f"cause, then `micam session start --resume {run.session_id}`")
            self._close(f"interrupted: {exc}")
            return
        if closed:
            status = _status_of(run.path)
            self._close(f"session {status}")
            if status == "complete":
                self._submit_final(run.path)

    def _submit_final(self, session: Path) -> None:
        """Queue the final calibration job of a complete session (never raises)."""
        try:
            job = job_for_session(session, "final")
        except Exception as exc:  # a damaged session (SessionError), a full disk, or a bug
            log.error("cannot make the final calibration job of %s: %s", session, exc,
                      exc_info=not isinstance(exc, SessionError | OSError | ValidationError))
            self.publish(ErrorEvent, message=f"session {session.name} is complete, but its "
                                             f"calibration job cannot be made: {exc}")
            return
        self.broker.submit(job)

    def _after_first_scan(self) -> None:
        """Once every session is indexed: queue the final jobs a full outbox lost, and offer
        (or resume) the newest interrupted session."""
        days = self.config.workers.keep_finished_days
        since = time.time_ns() - int(days * 86400e9)
        queued = {j.session_id for j in self.broker.outbox.jobs.values() if j.kind == "final"}
        owed = [s for s in reversed(self.index.completed_since(since))
                if s.name not in queued and not (s / CALIBRATION_DIR / RESULT_FILE).exists()]
        for session in owed[:RECONCILE_LIMIT]:
            log.warning("session %s is complete but has no calibration and no job; queueing "
                        "its final job again", session.name)
            self._submit_final(session)
        if len(owed) > RECONCILE_LIMIT:
            log.warning("%d more complete sessions of the last %g days have no calibration "
                        "and no job; they are not queued by themselves",
                        len(owed) - RECONCILE_LIMIT, days)
        left = self.index.newest_interrupted()
        if left is None or self.run is not None or self.terminating:
            return
        if self.config.resume_at_start == "auto":
            log.warning("session %s was interrupted; resuming it (resume_at_start = auto)", left)
            try:
                handlers.start(self, SessionStartArgs(resume=left))
            except Refusal as refusal:
                log.error("cannot resume session %s: %s", left, refusal.message)
            return
        log.warning("session %s was interrupted; continue it with `micam session start --resume "
                    "%s`", left, left)

    def step_completed(self, step: str) -> None:
        """After a step's end is journaled: a live calibration job once enough poses are in."""
        run = self.run
        workers = self.config.workers
        if run is None or not is_pose_step(step) or not workers.live:
            return
        if sum(is_pose_step(s) for s in run.completed()) >= workers.live_min_poses:
            try:
                self.broker.submit(job_for_session(run.path, "live"))
            except Exception as exc:  # a live job can wait a pose; a bug is logged in full
                log.error("cannot make a live calibration job of %s: %s", run.session_id, exc,
                          exc_info=not isinstance(exc, SessionError | OSError | ValidationError))

    def _close(self, reason: str) -> None:
        path = self.run.path if self.run is not None else None
        self.machine.go(State.STOPPING, reason)
        self.machine.go(State.IDLE, reason)
        if self.translog is not None:
            self.translog.close()
            self.translog = None
        self.run = None
        if path is not None:
            self.index.update(path)

    def _on_transition(self, t: Transition) -> None:
        run = self.run
        set_log_context(run.session_id if run else None, run.step if run else None)
        log.info("%s -> %s (%s)", t.previous.value, t.state.value, t.reason)
        if self.translog is not None:
            self.translog.append(previous=t.previous.value, state=t.state.value,
                                  reason=t.reason, step=run.step if run else None)
        self.publish(StateEvent, state=t.state.value, previous=t.previous.value, reason=t.reason)
        where = f"session {run.session_id}, {len(run.completed())}/{run.steps_total} steps" \
            if run else "no session"
        sd_notify(f"STATUS={t.state.value}; {where}")

    # -- requests ---------------------------------------------------------------------------

    def _handle(self, request: Request) -> BaseModel | dict[str, Any]:
        try:
            check_allowed(request.command, self.machine.state)
        except WrongState as exc:
            raise Refusal("wrong_state", str(exc)) from None
        return self._handlers[request.command](request)


def _guarded(what: str, work: Callable[..., object], *args: object) -> bool:
    """Run `work(*args)`; log any exception (a bug) instead of raising. True if it returned."""
    try:
        work(*args)
    except Exception:
        log.exception("internal error in %s; the daemon carries on", what)
        return False
    return True


def _status_of(session: Path) -> str:
    """How a session the daemon just closed reads ("unreadable" if it cannot be read)."""
    try:
        return SessionReader(session).status
    except SessionError as exc:
        log.error("cannot read the session %s just closed: %s", session, exc)
        return "unreadable"

