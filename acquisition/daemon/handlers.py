"""The daemon's request handlers: one function per command of the control protocol
(docs/protocol.md), each given the daemon and the request, returning the reply's result.

`Daemon._handle` checks that the state allows the command, then calls the handler of
`HANDLERS`; a handler refuses with `Refusal` (a reply with an error code), never with another
exception. Apart from the daemon's loop (service.py), so that the loop reads on its own.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel

from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.protocol import (
    CAMERA_MIN_VIEWS,
    PROTOCOL_VERSION,
    CaptureResult,
    ColumnInfo,
    DescribeResult,
    QualityInfo,
    RigInfo,
    SessionFileArgs,
    SessionReportArgs,
    SessionReportResult,
    SessionStartArgs,
    SessionSummary,
    StatusResult,
)
from acquisition.contracts.session import (
    SessionError,
    SessionReader,
    SessionWriter,
    write_atomic,
)
from acquisition.contracts.step_ids import is_pose_step

from ..sequencer import plan_steps
from .index import summarize
from .run import SessionEnding, SessionRun
from .server import Refusal
from .session_files import session_dir, session_file, session_report
from .states import WAITING_STATES, State
from .translog import TransitionLog

if TYPE_CHECKING:
    from .service import Daemon

Handler = Callable[["Daemon", Any], BaseModel | dict[str, Any]]
"""A request's handler: (the daemon, the request) -> the reply's result."""


def _open_run(daemon: Daemon) -> SessionRun:
    assert daemon.run is not None, "check_allowed admits this command only with a session"
    return daemon.run


def status(daemon: Daemon) -> StatusResult:
    run = daemon.run
    session = None
    if run is not None:
        session = summarize(run.session_id, run.path, "open", run.completed(),
                            run.writer.capture, run.created_utc)
    return StatusResult(
        state=daemon.machine.state.value, simulated=daemon.hardware.simulated, session=session,
        step=run.step if run else None,
        instruction=run.instruction.text if run and run.instruction else None,
        captures_requested=run.captures_requested if run else 0,
        last_capture=run.last_capture if run else None,
        paused=bool(run and run.paused), hands_free=daemon.config.hands_free.enabled,
        events_endpoint=daemon.server.events_endpoint,
        last_event_seq=daemon.server.last_event_seq, calibration=daemon.broker.status(),
        resumable=None if run else daemon.index.newest_interrupted(),
        cameras=run.cameras_seen() if run else [], coverage=run.coverage if run else [],
        previews_until_s=daemon.previews.remaining_s, live=daemon.live.status())


def describe(daemon: Daemon) -> DescribeResult:
    """What the daemon captures with, for clients that name and draw what events carry."""
    capture = daemon.hardware.config
    quality = daemon.config.quality
    return DescribeResult(
        simulated=daemon.hardware.simulated,
        columns=[ColumnInfo(column=j, board=c.board, channel=c.channel, role=c.role,
                            mic_id=c.mic_id, range_v=c.range_v)
                 for j, c in enumerate(capture.columns)],
        cameras=[c.name for c in capture.cameras],
        rig=RigInfo(corners_x=capture.rig.corners_x, corners_y=capture.rig.corners_y,
                    square_m=capture.rig.square_m,
                    speakers_m=[(p[0], p[1], p[2]) for p in capture.rig.speakers_m]),
        n_poses=capture.n_poses, max_poses=daemon.hardware.max_poses,
        quality=QualityInfo(clip_fraction=quality.clip_fraction,
                            min_level_dbfs=quality.min_level_dbfs,
                            min_snr_db=quality.min_snr_db,
                            min_channel_snr_db=quality.min_channel_snr_db),
        camera_min_views=CAMERA_MIN_VIEWS, live_min_poses=daemon.config.workers.live_min_poses,
        live=daemon.config.workers.live, preview_fps=daemon.config.previews.fps,
        preview_width=daemon.config.previews.width)


def _summary_of(daemon: Daemon, session_id: str) -> SessionSummary:
    """The summary of a session: the open one as `status` has it, else the index's."""
    current = status(daemon).session
    if current is not None and current.id == session_id:
        return current
    for entry in daemon.index.listing().sessions:
        if entry["id"] == session_id:
            return SessionSummary.model_validate(entry)
    raise SessionError(f"session {session_id} is not in the daemon's index (yet)")


def report(daemon: Daemon, args: SessionReportArgs) -> SessionReportResult:
    try:
        path = session_dir(daemon.session_root, args.session)
        return session_report(path, _summary_of(daemon, args.session))
    except SessionError as exc:
        raise Refusal("session_error", str(exc)) from None


def file(daemon: Daemon, args: SessionFileArgs) -> dict[str, Any]:
    try:
        return session_file(session_dir(daemon.session_root, args.session),
                            args.path).model_dump()
    except SessionError as exc:
        raise Refusal("session_error", str(exc)) from None


def list_sessions(daemon: Daemon) -> dict[str, Any]:
    """The indexed sessions (the open one as `status` describes it); no journal is read."""
    listing = daemon.index.listing()
    sessions = listing.sessions
    run = daemon.run
    if run is not None:
        current = status(daemon).session
        assert current is not None
        sessions = [current.model_dump(mode="json") if s["path"] == str(run.path) else s
                    for s in sessions]
        if not any(s["path"] == str(run.path) for s in listing.sessions):
            sessions.append(current.model_dump(mode="json"))
    return {"root": str(daemon.session_root), "sessions": sessions,
            "problems": listing.problems, "complete": listing.complete}


def start(daemon: Daemon, args: SessionStartArgs) -> dict[str, Any]:
    refusal = daemon.hardware.recording_refusal("a capture")
    if refusal is not None:
        raise Refusal("session_error", refusal)
    config = daemon.hardware.config
    if args.poses is not None:
        limit = daemon.hardware.max_poses
        if limit is not None and args.poses > limit:
            raise Refusal("session_error", f"the simulated world has {limit} poses; ask for "
                                           f"at most {limit} or configure more")
        config = config.model_copy(update={"n_poses": args.poses})
    try:
        writer = _reopen(daemon, args.resume) if args.resume else _create(daemon, config)
    except SessionError as exc:
        raise Refusal("session_error", str(exc)) from None
    except OSError as exc:  # a full or read-only disk under the session root
        raise Refusal("session_error", f"cannot write the session under "
                                       f"{daemon.session_root}: {exc}") from None
    try:
        created = SessionReader(writer.path).created_utc
        daemon.run = SessionRun(daemon, daemon.hardware, writer, daemon.config, created)
        daemon.translog = TransitionLog(writer.path)
    except BaseException:
        daemon.run = None
        writer.close()
        raise
    verb = "resumed" if args.resume else "created"
    daemon.machine.go(State.SESSION_OPEN, f"session {writer.session_id} {verb}")
    daemon.index.update(writer.path)
    session = status(daemon).session
    assert session is not None
    return {"session": session.model_dump(mode="json"), "resumed": bool(args.resume)}


def _create(daemon: Daemon, config: CaptureConfig) -> SessionWriter:
    session_id = f"{datetime.now(UTC):%Y-%m-%dT%H-%M-%SZ}_{uuid.uuid4().hex[:8]}"
    path = daemon.session_root / session_id
    writer = SessionWriter.create(path, capture=config.model_dump(mode="json"),
                                  session_id=session_id)
    for name, document in daemon.hardware.session_files.items():
        data = json.dumps(document, indent=1).encode()
        write_atomic(path / name, lambda fh: fh.write(data))  # called before the next
    return writer


def _reopen(daemon: Daemon, which: str) -> SessionWriter:
    path = _find_interrupted(daemon) if which == "last" else daemon.session_root / which
    writer = SessionWriter.resume(path)
    try:
        recorded = CaptureConfig.of_session(writer.capture, path)
    except SessionError:
        writer.close()
        raise
    ours = daemon.hardware.config.model_copy(update={"n_poses": recorded.n_poses})
    if recorded != ours:
        writer.close()
        raise SessionError(f"session {path.name} was recorded with another hardware "
                           "configuration than this daemon's; resume it with the daemon "
                           "configuration it was started with")
    return writer


def _find_interrupted(daemon: Daemon) -> Path:
    name = daemon.index.newest_interrupted()
    if name is not None:
        return daemon.session_root / name
    if not daemon.index.complete:
        raise SessionError(f"the daemon is still reading the sessions in {daemon.session_root}"
                           "; try again in a moment, or name the session to resume")
    raise SessionError(f"no interrupted session in {daemon.session_root}")


def stop(daemon: Daemon) -> dict[str, Any]:
    run = _open_run(daemon)
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
    return {"state": daemon.machine.state.value, "stopping": True}


def abort(daemon: Daemon) -> dict[str, Any]:
    _open_run(daemon).ending = SessionEnding("aborted", "aborted by the operator",
                                             after_burst=True)
    return {"state": daemon.machine.state.value, "stopping": True}


def pause(daemon: Daemon) -> dict[str, Any]:
    run = _open_run(daemon)
    run.paused = True
    if daemon.machine.state in WAITING_STATES:
        daemon.machine.go(State.PAUSED, "paused by the operator")
    return {"state": daemon.machine.state.value}


def unpause(daemon: Daemon) -> dict[str, Any]:
    run = _open_run(daemon)
    run.paused = False
    daemon.machine.go(run.waiting_state(), "resumed by the operator")
    return {"state": daemon.machine.state.value}


def capture(daemon: Daemon) -> CaptureResult:
    run = _open_run(daemon)
    number = run.request_capture("capture requested by the operator")
    return CaptureResult(number=number, step=run.next_step)


def redo(daemon: Daemon) -> dict[str, Any]:
    run = _open_run(daemon)
    run.redo = True
    return {"step": run.step}


HANDLERS: dict[str, Handler] = {
    "ping": lambda _, __: {"pong": True, "protocol": PROTOCOL_VERSION},
    "status": lambda d, _: status(d),
    "sessions.list": lambda d, _: list_sessions(d),
    "describe": lambda d, _: describe(d),
    "previews": lambda d, r: {"seconds": d.previews.request(r.args.seconds)},
    "session.report": lambda d, r: report(d, r.args),
    "session.file": lambda d, r: file(d, r.args),
    "session.start": lambda d, r: start(d, r.args),
    "session.stop": lambda d, _: stop(d),
    "session.abort": lambda d, _: abort(d),
    "session.pause": lambda d, _: pause(d),
    "session.resume": lambda d, _: unpause(d),
    "capture": lambda d, _: capture(d),
    "redo": lambda d, _: redo(d),
    "live.start": lambda d, r: d.live.start(r.args),
    "live.stop": lambda d, _: d.live.stop(),
    "live.record": lambda d, r: d.live.record(r.args),
}
"""Every command's handler, by its name in the protocol."""
