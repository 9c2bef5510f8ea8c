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

import json
import logging
import time
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import zmq
from pydantic import BaseModel, ValidationError

from acquisition.contracts.capture_config import CaptureConfig
from ..live.mode import POLL_S as LIVE_POLL_S
from ..sequencer import plan_steps
from acquisition.contracts.session import SessionError, SessionReader, SessionWriter
from acquisition.contracts.session import write_atomic
from acquisition.contracts.step_ids import is_pose_step
from .broker import CALIBRATION_DIR, JOBS_QUEUE, RESULT_FILE, Broker
from .config import DaemonConfig
from .files import CHUNK_QUEUE, FETCH_QUEUE, MAX_FETCH_BYTES, FileServer
from .hardware import Hardware
from .index import SessionIndex, summarize
from .jobs import job_for_session
from .live_control import LiveControl
from .outbox import Outbox
from .previews import Previews
from acquisition.contracts.protocol import (
    CAMERA_MIN_VIEWS,
    PROTOCOL_VERSION,
    CaptureResult,
    ColumnInfo,
    DescribeResult,
    ErrorEvent,
    QualityInfo,
    Request,
    RigInfo,
    SessionFileArgs,
    SessionReportArgs,
    SessionReportResult,
    SessionStartArgs,
    SessionSummary,
    StateEvent,
    StatusResult,
)
from .run import SessionEnding, SessionRun
from .server import ControlServer, Refusal
from .session_files import session_dir, session_file, session_report
from .states import WAITING_STATES, State, StateMachine, Transition, WrongState, check_allowed
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
        self._translog: TransitionLog | None = None
        self._reconciled = False
        self._handlers: dict[str, Callable[[Any], BaseModel | dict[str, Any]]] = {
            "ping": lambda _: {"pong": True, "protocol": PROTOCOL_VERSION},
            "status": lambda _: self.status(),
            "sessions.list": lambda _: self.list_sessions(),
            "describe": lambda _: self.describe(),
            "previews": lambda r: {"seconds": self.previews.request(r.args.seconds)},
            "session.report": lambda r: self._report(r.args),
            "session.file": lambda r: self._file(r.args),
            "session.start": lambda r: self._start(r.args),
            "session.stop": lambda _: self._stop(),
            "session.abort": lambda _: self._abort(),
            "session.pause": lambda _: self._pause(),
            "session.resume": lambda _: self._unpause(),
            "capture": lambda _: self._capture(),
            "redo": lambda _: self._redo(),
            "live.start": lambda r: self.live.start(r.args),
            "live.stop": lambda _: self.live.stop(),
            "live.record": lambda r: self.live.record(r.args),
        }
        rig = hardware.config.rig
        self.previews = Previews(config.previews, hardware.cameras,
                                 (rig.corners_x, rig.corners_y), self.publish,
                                 config.camera_timeout_s)
        self.index = SessionIndex(self.session_root,
                                  busy=lambda: self.machine.state is State.CAPTURING)
        self.server = ControlServer(config.sockets, self._handle)
        self.live = LiveControl(hardware, self.machine, self.session_root, self.publish,
                                self.server.publish_frames, config.camera_timeout_s)
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
                self._start(SessionStartArgs(resume=left))
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
        if self._translog is not None:
            self._translog.close()
            self._translog = None
        self.run = None
        if path is not None:
            self.index.update(path)

    def _on_transition(self, t: Transition) -> None:
        run = self.run
        set_log_context(run.session_id if run else None, run.step if run else None)
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
            last_event_seq=self.server.last_event_seq, calibration=self.broker.status(),
            resumable=None if run else self.index.newest_interrupted(),
            cameras=run.cameras_seen() if run else [], coverage=run.coverage if run else [],
            previews_until_s=self.previews.remaining_s, live=self.live.status())

    def describe(self) -> DescribeResult:
        """What the daemon captures with, for clients that name and draw what events carry."""
        capture = self.hardware.config
        quality = self.config.quality
        return DescribeResult(
            simulated=self.hardware.simulated,
            columns=[ColumnInfo(column=j, board=c.board, channel=c.channel, role=c.role,
                                mic_id=c.mic_id, range_v=c.range_v)
                     for j, c in enumerate(capture.columns)],
            cameras=[c.name for c in capture.cameras],
            rig=RigInfo(corners_x=capture.rig.corners_x, corners_y=capture.rig.corners_y,
                        square_m=capture.rig.square_m,
                        speakers_m=[(p[0], p[1], p[2]) for p in capture.rig.speakers_m]),
            n_poses=capture.n_poses, max_poses=self.hardware.max_poses,
            quality=QualityInfo(clip_fraction=quality.clip_fraction,
                                min_level_dbfs=quality.min_level_dbfs,
                                min_snr_db=quality.min_snr_db,
                                min_channel_snr_db=quality.min_channel_snr_db),
            camera_min_views=CAMERA_MIN_VIEWS, live_min_poses=self.config.workers.live_min_poses,
            live=self.config.workers.live, preview_fps=self.config.previews.fps,
            preview_width=self.config.previews.width)

    def _summary_of(self, session_id: str) -> SessionSummary:
        """The summary of a session: the open one as `status` has it, else the index's."""
        current = self.status().session
        if current is not None and current.id == session_id:
            return current
        for entry in self.index.listing().sessions:
            if entry["id"] == session_id:
                return SessionSummary.model_validate(entry)
        raise SessionError(f"session {session_id} is not in the daemon's index (yet)")

    def _report(self, args: SessionReportArgs) -> SessionReportResult:
        try:
            path = session_dir(self.session_root, args.session)
            return session_report(path, self._summary_of(args.session))
        except SessionError as exc:
            raise Refusal("session_error", str(exc)) from None

    def _file(self, args: SessionFileArgs) -> dict[str, Any]:
        try:
            return session_file(session_dir(self.session_root, args.session),
                                args.path).model_dump()
        except SessionError as exc:
            raise Refusal("session_error", str(exc)) from None

    def list_sessions(self) -> dict[str, Any]:
        """The indexed sessions (the open one as `status` describes it); no journal is read."""
        listing = self.index.listing()
        sessions = listing.sessions
        run = self.run
        if run is not None:
            current = self.status().session
            assert current is not None
            sessions = [current.model_dump(mode="json") if s["path"] == str(run.path) else s
                        for s in sessions]
            if not any(s["path"] == str(run.path) for s in listing.sessions):
                sessions.append(current.model_dump(mode="json"))
        return {"root": str(self.session_root), "sessions": sessions,
                "problems": listing.problems, "complete": listing.complete}

    def _start(self, args: SessionStartArgs) -> dict[str, Any]:
        refusal = self.hardware.recording_refusal("a capture")
        if refusal is not None:
            raise Refusal("session_error", refusal)
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
        except OSError as exc:  # a full or read-only disk under the session root
            raise Refusal("session_error", f"cannot write the session under "
                                           f"{self.session_root}: {exc}") from None
        try:
            created = SessionReader(writer.path).created_utc
            self.run = SessionRun(self, self.hardware, writer, self.config, created)
            self._translog = TransitionLog(writer.path)
        except BaseException:
            self.run = None
            writer.close()
            raise
        verb = "resumed" if args.resume else "created"
        self.machine.go(State.SESSION_OPEN, f"session {writer.session_id} {verb}")
        self.index.update(writer.path)
        session = self.status().session
        assert session is not None
        return {"session": session.model_dump(mode="json"), "resumed": bool(args.resume)}

    def _create(self, config: CaptureConfig) -> SessionWriter:
        session_id = f"{datetime.now(UTC):%Y-%m-%dT%H-%M-%SZ}_{uuid.uuid4().hex[:8]}"
        path = self.session_root / session_id
        writer = SessionWriter.create(path, capture=config.model_dump(mode="json"),
                                      session_id=session_id)
        for name, document in self.hardware.session_files.items():
            data = json.dumps(document, indent=1).encode()
            write_atomic(path / name, lambda fh: fh.write(data))  # called before the next
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
        name = self.index.newest_interrupted()
        if name is not None:
            return self.session_root / name
        if not self.index.complete:
            raise SessionError(f"the daemon is still reading the sessions in {self.session_root}"
                               "; try again in a moment, or name the session to resume")
        raise SessionError(f"no interrupted session in {self.session_root}")

    def _stop(self) -> dict[str, Any]:
        run = self._open_run()
        done = run.completed()
        missing = [s.id for s in plan_steps(run.capture)
                   if not is_pose_step(s.id) and s.id not in done]
        if missing:
            raise Refusal("wrong_state",
                          f"cannot stop: {', '.join(missing)} not recorded yet, and calibration "
                          "needs them; capture them, or `micam session abort`")
        poses = sum(is_pose_step(s) for s in done)
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

