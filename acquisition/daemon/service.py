"""The daemon: one thread that serves the sockets, drives the capture and pings the watchdog.

There is no second thread to race with: while a session waits for the operator, the run's
`perform` serves the sockets; while a step is captured, the sockets are served between files.
So a request is answered within one burst, and a wedged hardware call stops the watchdog
pings, as systemd's watchdog intends.
"""

from __future__ import annotations

import json
import logging
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import zmq
from pydantic import BaseModel

from ..capture_config import CaptureConfig
from ..sequencer import plan_steps
from ..session import SessionError, SessionReader, SessionWriter
from ..session._atomic import write_atomic
from .broker import Broker
from .config import DaemonConfig
from .files import FileServer
from .hardware import Hardware
from .jobs import job_for_session
from .outbox import Outbox
from .protocol import (
    PROTOCOL_VERSION,
    CaptureResult,
    ErrorEvent,
    Request,
    SessionsResult,
    SessionStartArgs,
    SessionSummary,
    StateEvent,
    StatusResult,
)
from .run import SessionEnding, SessionRun
from .server import ControlServer, Refusal
from .states import WAITING_STATES, State, StateMachine, Transition, WrongState, check_allowed
from .systemd import Watchdog, sd_notify
from .translog import TransitionLog

log = logging.getLogger("micam.daemon")


def summarize(session_id: str, path: Path, status: str, completed: dict[str, Any],
              capture: dict, created_utc: datetime) -> SessionSummary:
    """A session's summary for `status` and `sessions.list`."""
    return SessionSummary(
        id=session_id, path=str(path), status=status, steps_done=len(completed),
        steps_total=len(plan_steps(CaptureConfig.of_session(capture, path))),
        poses_done=sum(s.startswith("pose/") for s in completed),
        n_poses=capture["n_poses"], created_utc=created_utc)


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
        self._translog: TransitionLog | None = None
        self._handlers: dict[str, Callable[[Any], BaseModel | dict[str, Any]]] = {
            "ping": lambda _: {"pong": True, "protocol": PROTOCOL_VERSION},
            "status": lambda _: self.status(),
            "sessions.list": lambda _: self.list_sessions(),
            "session.start": lambda r: self._start(r.args),
            "session.stop": lambda _: self._stop(),
            "session.abort": lambda _: self._abort(),
            "session.pause": lambda _: self._pause(),
            "session.resume": lambda _: self._unpause(),
            "capture": lambda _: self._capture(),
            "redo": lambda _: self._redo(),
        }
        self.server = ControlServer(config.sockets, self._handle)
        try:
            self.broker, self.files = self._open_broker()
        except BaseException:
            self.server.close()
            raise

    def _open_broker(self) -> tuple[Broker, FileServer]:
        """The calibration hand-off: the outbox, the jobs socket and the file server."""
        workers = self.config.workers
        default = self.session_root.with_name(self.session_root.name + ".outbox")
        outbox = Outbox((workers.outbox or default).expanduser())
        requeued = outbox.load()
        sockets = self.config.sockets
        broker = Broker(self.server.bind(zmq.ROUTER, sockets.jobs_endpoint), workers, outbox,
                        self.publish)
        files = FileServer(self.server.bind(zmq.ROUTER, sockets.files_endpoint),
                           outbox.jobs.get)
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
            left = self._find_interrupted().name
            log.warning("session %s was interrupted; continue it with `micam session start "
                        "--resume %s`", left, left)
        except SessionError:
            pass
        try:
            while True:
                run = self.run
                if run is not None and run.ready():
                    self._advance(run)
                elif self.terminating and run is None:
                    break
                else:
                    self.service(self.config.poll_interval_s)
        finally:
            sd_notify("STOPPING=1")
            if self.run is not None:  # only on a second signal: left resumable
                self.run.writer.close()
            self.broker.close()
            self.files.sock.close(linger=0)
            self.server.close()
            self.hardware.close()
            log.info("stopped")

    def service(self, timeout_s: float) -> None:
        """One turn of the loop: watchdog, requests (waiting up to `timeout_s`), hands-free."""
        self.watchdog.tick()
        run = self.run
        if self.terminating and run is not None and (run.ending is None
                                                     or not run.ending.after_burst):
            run.ending = SessionEnding("aborted", "the daemon was stopped (SIGTERM)",
                                       after_burst=True)
        self.server.serve(timeout_s)
        self.broker.tick()
        if self.run is not None:
            self.run.hands_free_tick()

    def terminate(self) -> None:
        """Ask the daemon to end the current burst, close any session as aborted and exit."""
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
            status = SessionReader(run.path).status
            self._close(f"session {status}")
            if status == "complete":
                self.broker.submit(job_for_session(run.path, "final"))

    def step_completed(self, step: str) -> None:
        """After a step's end is journaled: a live calibration job once enough poses are in."""
        run = self.run
        workers = self.config.workers
        if run is None or not step.startswith("pose/") or not workers.live:
            return
        if sum(s.startswith("pose/") for s in run.completed()) >= workers.live_min_poses:
            self.broker.submit(job_for_session(run.path, "live"))

    def _close(self, reason: str) -> None:
        self.machine.go(State.STOPPING, reason)
        self.machine.go(State.IDLE, reason)
        if self._translog is not None:
            self._translog.close()
            self._translog = None
        self.run = None

    def _on_transition(self, t: Transition) -> None:
        run = self.run
        log.info("%s -> %s (%s)", t.previous.value, t.state.value, t.reason)
        if self._translog is not None:
            self._translog.append(previous=t.previous.value, state=t.state.value,
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

    def _open_run(self) -> SessionRun:
        assert self.run is not None, "check_allowed admits this command only with a session"
        return self.run

    def status(self) -> StatusResult:
        run = self.run
        session = None
        if run is not None:
            session = summarize(run.session_id, run.path, "open", run.completed(),
                                run.writer.capture, run.created_utc)
        return StatusResult(
            state=self.machine.state.value, simulated=self.hardware.simulated, session=session,
            step=run.step if run else None,
            instruction=run.instruction.text if run and run.instruction else None,
            captures_requested=run.captures_requested if run else 0,
            last_capture=run.last_capture if run else None,
            paused=bool(run and run.paused), hands_free=self.config.hands_free.enabled,
            events_endpoint=self.server.events_endpoint,
            last_event_seq=self.server.last_event_seq, calibration=self.broker.status())

    def list_sessions(self) -> SessionsResult:
        sessions, problems = [], []
        for path in sorted(p for p in self.session_root.iterdir() if p.is_dir()):
            if not (path / "journal.jsonl").is_file():
                continue
            if self.run is not None and path == self.run.path:
                sessions.append(self.status().session)
                continue
            try:
                reader = SessionReader(path)
                sessions.append(summarize(reader.session_id, path, reader.status,
                                          reader.steps(), reader.capture, reader.created_utc))
            except (SessionError, ValueError, KeyError) as exc:
                problems.append(f"{path.name}: {exc}")
        return SessionsResult(root=str(self.session_root), sessions=sessions,
                              problems=problems)

    def _start(self, args: SessionStartArgs) -> dict[str, Any]:
        config = self.hardware.config
        if args.poses is not None:
            limit = self.hardware.max_poses
            if limit is not None and args.poses > limit:
                raise Refusal("session_error", f"the simulated world has {limit} poses; ask for "
                                               f"at most {limit} or configure more")
            config = config.model_copy(update={"n_poses": args.poses})
        try:
            writer = self._reopen(args.resume) if args.resume else self._create(config)
        except SessionError as exc:
            raise Refusal("session_error", str(exc)) from None
        created = SessionReader(writer.path).created_utc
        self.run = SessionRun(self, self.hardware, writer, self.config, created)
        self._translog = TransitionLog(writer.path)
        verb = "resumed" if args.resume else "created"
        self.machine.go(State.SESSION_OPEN, f"session {writer.session_id} {verb}")
        return {"session": self.status().session.model_dump(mode="json"), "resumed":
                bool(args.resume)}

    def _create(self, config: CaptureConfig) -> SessionWriter:
        session_id = f"{datetime.now(UTC):%Y-%m-%dT%H-%M-%SZ}_{uuid.uuid4().hex[:8]}"
        path = self.session_root / session_id
        writer = SessionWriter.create(path, capture=config.model_dump(mode="json"),
                                      session_id=session_id)
        for name, document in self.hardware.session_files.items():
            text = json.dumps(document, indent=1).encode()
            write_atomic(path / name, lambda fh, text=text: fh.write(text))
        return writer

    def _reopen(self, which: str) -> SessionWriter:
        path = self._find_interrupted() if which == "last" else self.session_root / which
        writer = SessionWriter.resume(path)
        try:
            recorded = CaptureConfig.of_session(writer.capture, path)
        except SessionError:
            writer.close()
            raise
        ours = self.hardware.config.model_copy(update={"n_poses": recorded.n_poses})
        if recorded != ours:
            writer.close()
            raise SessionError(f"session {path.name} was recorded with another hardware "
                               "configuration than this daemon's; resume it with the daemon "
                               "configuration it was started with")
        return writer

    def _find_interrupted(self) -> Path:
        for path in sorted(self.session_root.iterdir(), reverse=True):
            if (path / "journal.jsonl").is_file():
                try:
                    if SessionReader(path).status == "interrupted":
                        return path
                except SessionError:
                    continue
        raise SessionError(f"no interrupted session in {self.session_root}")

    def _stop(self) -> dict[str, Any]:
        run = self._open_run()
        done = run.completed()
        missing = [s.id for s in plan_steps(run.capture)
                   if not s.id.startswith("pose/") and s.id not in done]
        if missing:
            raise Refusal("wrong_state",
                          f"cannot stop: {', '.join(missing)} not recorded yet, and calibration "
                          "needs them; capture them, or `micam session abort`")
        poses = sum(s.startswith("pose/") for s in done)
        run.ending = SessionEnding("success", f"stopped by the operator after {poses} of "
                                              f"{run.capture.n_poses} poses", after_burst=False)
        return {"state": self.machine.state.value, "stopping": True}

    def _abort(self) -> dict[str, Any]:
        self._open_run().ending = SessionEnding("aborted", "aborted by the operator",
                                                after_burst=True)
        return {"state": self.machine.state.value, "stopping": True}

    def _pause(self) -> dict[str, Any]:
        run = self._open_run()
        run.paused = True
        if self.machine.state in WAITING_STATES:
            self.machine.go(State.PAUSED, "paused by the operator")
        return {"state": self.machine.state.value}

    def _unpause(self) -> dict[str, Any]:
        run = self._open_run()
        run.paused = False
        self.machine.go(run.waiting_state(), "resumed by the operator")
        return {"state": self.machine.state.value}

    def _capture(self) -> CaptureResult:
        run = self._open_run()
        number = run.request_capture("capture requested by the operator")
        return CaptureResult(number=number, step=run.next_step)

    def _redo(self) -> dict[str, Any]:
        run = self._open_run()
        run.redo = True
        return {"step": run.step}
