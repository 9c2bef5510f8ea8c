"""The daemon's ZeroMQ messages: versioned JSON, validated by pydantic on both ends.

Control (REQ/REP): a client sends one `Request` frame; the daemon always answers with one
`Reply` frame, `ok` with a command-specific `result`, or not ok with an `ErrorInfo` whose `code`
a program can switch on and whose `message` a person can act on.

Events (PUB/SUB): two frames, the event type as topic (so a subscriber may filter) and the
`Event` JSON. `seq` increases by one per event of a daemon run, so a gap tells a subscriber it
missed something; the `status` reply carries the last `seq` as a snapshot point.

docs/protocol.md documents every message; `json_schemas()` generates their JSON Schemas.

Version 2 added what an operator's page needs (`micam web`): `describe` (which column is which
microphone, the cameras, the rig, the quality thresholds), `previews` (camera previews as
`preview` events while a client asks for them), `session.report` and `session.file` (a
session's quality and calibration files), per-channel flags in `levels`, and the poses each
camera has seen in `progress` and `status`. Both ends refuse a message of another version.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated, Any, Final, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from acquisition.contracts.safe_names import SafeName, SafeRelativePath
from .job_messages import LiveUpdate, job_schemas

PROTOCOL_VERSION: Final = 2
CAMERA_MIN_VIEWS = 4
"""Board views a camera needs to be calibrated (calibration.camera.camera_calibration.MIN_VIEWS;
a test keeps the two equal): a camera with fewer is left out of the calibration."""

ErrorCode = Literal[
    "bad_request",  # not JSON, not an object, a field missing or of the wrong type
    "unsupported_version",  # `v` is not PROTOCOL_VERSION
    "unknown_command",  # `command` names no command
    "too_large",  # the request exceeds the daemon's max_message_bytes
    "wrong_state",  # the command makes no sense in the daemon's current state
    "session_error",  # the session cannot be created, resumed or found
    "internal",  # a bug: the daemon logged a traceback and keeps running
]


class _Message(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# -- requests --------------------------------------------------------------------------------


class NoArgs(_Message):
    """Arguments of a command that takes none."""


class SessionStartArgs(_Message):
    poses: int | None = Field(
        default=None, ge=1, le=10_000,
        description="rig poses to capture; default: the daemon's configuration")
    resume: str | None = Field(
        default=None, max_length=128, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$",
        description="id of an interrupted session to continue, or 'last' for the newest one")


class PreviewsArgs(_Message):
    seconds: float = Field(
        default=10.0, ge=0.0, le=60.0,
        description="publish `preview` events for this long from now (0: stop); ask again "
                    "before it runs out to keep them coming")


class LiveStartArgs(_Message):
    seconds: float = Field(default=10.0, ge=1.0, le=30.0,
                           description="the ring buffer holds this many of the latest seconds "
                                       "(14 MB a second for 73 columns at 96 kS/s)")
    camera_fps: float = Field(default=10.0, gt=0.0, le=30.0,
                              description="camera frames per second while live")
    cameras: list[SafeName] | None = Field(default=None, max_length=16,
                                           description="the cameras streamed (default: all)")
    samples: bool = Field(default=True,
                          description="publish the time data (`samples` messages) for clients "
                                      "that image it")


class LiveRecordArgs(_Message):
    seconds: float = Field(default=5.0, gt=0.0, le=30.0,
                           description="record this many of the latest seconds of the ring")


class SessionFileArgs(_Message):
    session: SafeName = Field(description="the session's id")
    path: SafeRelativePath = Field(
        description="a file under the session's calibration/ directory, e.g. "
                    "calibration/result.json")


class SessionReportArgs(_Message):
    session: SafeName = Field(description="the session's id")


class _Request(_Message):
    v: Literal[2] = PROTOCOL_VERSION
    id: str = Field(default="", max_length=64, description="echoed in the reply")


class PingRequest(_Request):
    command: Literal["ping"] = "ping"
    args: NoArgs = NoArgs()


class StatusRequest(_Request):
    command: Literal["status"] = "status"
    args: NoArgs = NoArgs()


class SessionsListRequest(_Request):
    command: Literal["sessions.list"] = "sessions.list"
    args: NoArgs = NoArgs()


class DescribeRequest(_Request):
    """What the daemon captures with: columns, cameras, rig, quality thresholds."""

    command: Literal["describe"] = "describe"
    args: NoArgs = NoArgs()


class PreviewsRequest(_Request):
    """Ask for camera previews (`preview` events) for the next `seconds`."""

    command: Literal["previews"] = "previews"
    args: PreviewsArgs = PreviewsArgs()


class SessionReportRequest(_Request):
    """A session's summary, its poses' quality and the files of its calibration."""

    command: Literal["session.report"] = "session.report"
    args: SessionReportArgs


class SessionFileRequest(_Request):
    """One file of a session's calibration directory (result, live update, report, figures)."""

    command: Literal["session.file"] = "session.file"
    args: SessionFileArgs


class SessionStartRequest(_Request):
    command: Literal["session.start"] = "session.start"
    args: SessionStartArgs = SessionStartArgs()


class SessionStopRequest(_Request):
    """End the session after the current step, as complete (needs every reference step)."""

    command: Literal["session.stop"] = "session.stop"
    args: NoArgs = NoArgs()


class SessionPauseRequest(_Request):
    command: Literal["session.pause"] = "session.pause"
    args: NoArgs = NoArgs()


class SessionResumeRequest(_Request):
    """Continue a paused session (an interrupted one is continued by session.start resume)."""

    command: Literal["session.resume"] = "session.resume"
    args: NoArgs = NoArgs()


class SessionAbortRequest(_Request):
    """End the session after the current burst, as aborted; it can never be continued."""

    command: Literal["session.abort"] = "session.abort"
    args: NoArgs = NoArgs()


class CaptureRequest(_Request):
    """The set-up the daemon asked for is ready: capture the current step."""

    command: Literal["capture"] = "capture"
    args: NoArgs = NoArgs()


class RedoRequest(_Request):
    """Throw away the step being captured (after the current burst) and capture it again."""

    command: Literal["redo"] = "redo"
    args: NoArgs = NoArgs()


class LiveStartRequest(_Request):
    """Enter live mode: every board scanning without end, the cameras streaming (idle only)."""

    command: Literal["live.start"] = "live.start"
    args: LiveStartArgs = LiveStartArgs()


class LiveStopRequest(_Request):
    """Leave live mode."""

    command: Literal["live.stop"] = "live.stop"
    args: NoArgs = NoArgs()


class LiveRecordRequest(_Request):
    """Store the latest seconds of live mode (session format and Acoular's HDF5 layout)."""

    command: Literal["live.record"] = "live.record"
    args: LiveRecordArgs = LiveRecordArgs()


_REQUESTS = (PingRequest, StatusRequest, SessionsListRequest, DescribeRequest, PreviewsRequest,
             SessionReportRequest, SessionFileRequest, SessionStartRequest, SessionStopRequest,
             SessionPauseRequest, SessionResumeRequest, SessionAbortRequest, CaptureRequest,
             RedoRequest, LiveStartRequest, LiveStopRequest, LiveRecordRequest)
Request = Annotated[
    PingRequest | StatusRequest | SessionsListRequest | DescribeRequest | PreviewsRequest
    | SessionReportRequest | SessionFileRequest | SessionStartRequest | SessionStopRequest
    | SessionPauseRequest | SessionResumeRequest | SessionAbortRequest | CaptureRequest
    | RedoRequest | LiveStartRequest | LiveStopRequest | LiveRecordRequest,
    Field(discriminator="command"),
]
REQUEST_TYPES: dict[str, type[_Request]] = {
    t.model_fields["command"].default: t for t in _REQUESTS
}
COMMANDS = tuple(REQUEST_TYPES)


class Envelope(BaseModel):
    """The fields every request must have, read before the command's own model is chosen."""

    model_config = ConfigDict(extra="allow")

    v: int
    id: str = Field(default="", max_length=64)
    command: str = Field(max_length=64)


# -- replies ---------------------------------------------------------------------------------


class ErrorInfo(_Message):
    code: ErrorCode
    message: str


class Reply(_Message):
    v: Literal[2] = PROTOCOL_VERSION
    id: str = ""
    ok: bool
    result: dict[str, Any] | None = None
    error: ErrorInfo | None = None


class LastCapture(_Message):
    """How the operator's most recent capture ended."""

    number: int = Field(description="counts the operator's captures in this daemon run")
    step: str
    outcome: Literal["complete", "abandoned"]
    reason: str = ""
    warnings: list[str] = []


class SessionSummary(_Message):
    id: str
    path: str
    status: str
    steps_done: int
    steps_total: int
    poses_done: int
    n_poses: int
    created_utc: datetime


class WorkerSummary(_Message):
    name: str
    job: str | None = Field(default=None, description="the job it holds, if any")


class CalibrationStatus(_Message):
    """The calibration hand-off: connected workers and the jobs of the outbox."""

    workers: list[WorkerSummary] = []
    pending: int = 0
    leased: int = 0
    done: int = 0
    failed: int = 0


class CameraPoses(_Message):
    """How many completed poses of the open session a camera found the board in."""

    camera: str
    poses_seen: int = Field(ge=0)
    board_views: int | None = Field(
        default=None, ge=0, description="completed steps whose image shows the board, the "
                                        "refmic image's included: the views the camera's "
                                        "calibration gets (None: a daemon that does not say)")
    views_left: int | None = Field(
        default=None, ge=0, description="steps still to capture that take a board view")


class PoseOutline(_Message):
    """Where the board was in camera 0's image at a completed pose: its four outermost inner
    corners, as fractions of the image's width and height (0..1, x right, y down)."""

    step: str
    outline: list[tuple[float, float]] = Field(max_length=4)


class LiveStatus(_Message):
    """Live mode: how far the scan is, how much the ring holds, how far behind the clock the
    daemon reads (it must stay near 0: the boards' FIFOs hold well under a second)."""

    sample: int = Field(description="samples read per column since live mode began")
    sample_rate_hz: float
    held_s: float = Field(description="seconds of time data in the ring buffer")
    capacity_s: float
    behind_s: float = Field(description="the scan's time minus the time read")
    max_behind_s: float = Field(description="the largest behind_s since live mode began")
    frames: int = Field(description="camera frames taken")


class LiveRecordResult(_Message):
    path: str = Field(description="the recording's session directory")
    session: str
    seconds: float
    acoular_file: str = Field(description="time_data.h5: Acoular's HDF5 time-data layout")


class StatusResult(_Message):
    """The `status` reply: a snapshot of everything `watch` shows."""

    state: str
    simulated: bool
    session: SessionSummary | None = None
    step: str | None = Field(default=None, description="the step being waited for or captured")
    instruction: str | None = None
    captures_requested: int = 0
    last_capture: LastCapture | None = None
    paused: bool = False
    hands_free: bool = False
    events_endpoint: str
    last_event_seq: int
    calibration: CalibrationStatus = CalibrationStatus()
    resumable: str | None = Field(
        default=None, description="the newest interrupted session, which `session.start` "
                                  "with `resume` continues (offered while idle)")
    cameras: list[CameraPoses] = Field(
        default=[], description="the open session: completed poses with the board found, by "
                                "camera")
    coverage: list[PoseOutline] = Field(
        default=[], description="the open session: the board in camera 0's image at each "
                                "completed pose (the most recent MAX_COVERAGE)")
    previews_until_s: float = Field(
        default=0.0, description="seconds from now during which previews are published")
    live: LiveStatus | None = Field(default=None, description="live mode, while it runs")


class SessionsResult(_Message):
    root: str
    sessions: list[SessionSummary]
    problems: list[str] = Field(default=[], description="session directories that cannot be read")
    complete: bool = Field(
        default=True, description="False while the daemon is still reading sessions it has not "
                                  "indexed yet: the list may lack some")


class ColumnInfo(_Message):
    """One column of every recording: its board and input, and what it records."""

    column: int
    board: str
    channel: int
    role: Literal["mic", "reference"]
    mic_id: int | None = None
    range_v: float | None = Field(default=None, description="volts at full scale (code 32768)")


class RigInfo(_Message):
    """The calibration rig, as a page draws it (rig frame, metres)."""

    corners_x: int
    corners_y: int
    square_m: float
    speakers_m: list[tuple[float, float, float]]


class QualityInfo(_Message):
    """The thresholds the daemon's quality checks use (docs/protocol.md, Quality checks)."""

    clip_fraction: float
    min_level_dbfs: float
    min_snr_db: float
    min_channel_snr_db: float


class DescribeResult(_Message):
    """The `describe` reply: what a client needs to name and draw what the events carry."""

    simulated: bool
    columns: list[ColumnInfo]
    cameras: list[str]
    rig: RigInfo
    n_poses: int = Field(description="poses of a session started without `poses`")
    max_poses: int | None = Field(default=None, description="the most a session may ask for")
    quality: QualityInfo
    camera_min_views: int = Field(
        description="board views a camera needs to be calibrated (fewer: it is left out)")
    live_min_poses: int = Field(description="poses completed before the first live "
                                            "calibration runs (with live calibration on; a "
                                            "count: 4 is after pose 3)")
    live: bool
    preview_fps: float
    preview_width: int


class CalibrationFile(_Message):
    path: str = Field(description="relative to the session directory")
    bytes: int


class PoseQuality(_Message):
    """A completed step's quality.json, in short."""

    step: str
    checkerboard_found: dict[str, bool] = {}
    warnings: list[str] = []


class SessionReportResult(_Message):
    session: SessionSummary
    steps: list[PoseQuality]
    files: list[CalibrationFile] = Field(description="the files of calibration/ (at most "
                                                     "MAX_REPORT_FILES)")


class SessionFileResult(_Message):
    path: str
    bytes: int
    content_b64: str = Field(description="the file's bytes, base64")


class CaptureResult(_Message):
    number: int = Field(description="wait until status.last_capture.number reaches it")
    step: str


# -- events ----------------------------------------------------------------------------------


class _Event(_Message):
    v: Literal[2] = PROTOCOL_VERSION
    seq: int = Field(ge=0)
    time_utc: datetime
    session_id: str | None = None


class StateEvent(_Event):
    type: Literal["state"] = "state"
    state: str
    previous: str
    reason: str


class InstructionEvent(_Event):
    """What the operator must set up before capturing `step`."""

    type: Literal["instruction"] = "instruction"
    step: str
    kind: str
    text: str


class ProgressEvent(_Event):
    """After every completed step: the counts, and for a pose the board's place in camera 0."""

    type: Literal["progress"] = "progress"
    steps_done: int
    steps_total: int
    poses_done: int
    n_poses: int
    step: str
    cameras: list[CameraPoses] = []
    outline: PoseOutline | None = None


class PreviewEvent(_Event):
    """A downscaled JPEG of a camera's view, the board's corners drawn on it when found.
    `step` is the step whose image it is, or None for a look while waiting."""

    type: Literal["preview"] = "preview"
    camera: str
    step: str | None = None
    found: bool
    width: int
    height: int
    source_width: int
    source_height: int
    jpeg_b64: str


class LiveModeEvent(_Event):
    """Live mode began or ended (`reason`: why, e.g. a board's overrun)."""

    type: Literal["live_mode"] = "live_mode"
    running: bool
    reason: str = ""


class LiveRecordedEvent(_Event):
    """A `live.record` is on disk (`error` empty), or failed (`error` says why)."""

    type: Literal["live_recorded"] = "live_recorded"
    path: str
    error: str = ""


class LiveFrameEvent(_Event):
    """A camera frame of live mode, downscaled JPEG, taken when the scan had reached `sample`
    (samples per column since live mode began)."""

    type: Literal["live_frame"] = "live_frame"
    camera: str
    sample: int
    width: int
    height: int
    source_width: int
    source_height: int
    jpeg_b64: str


class LevelsEvent(_Event):
    """Per-channel levels of one recording (dBFS: 0 = full scale of the channel's range), one
    value per column (`describe` names them). `listening`: the columns that should hear the
    speaker (the reference microphone, or every microphone); `dead_channels`: microphones below
    `min_channel_snr_db` at a pose; `low_snr_channels`: listening columns below `min_snr_db`
    that are not dead."""

    type: Literal["levels"] = "levels"
    step: str
    file: str
    rms_dbfs: list[float]
    peak_dbfs: list[float]
    snr_db: list[float]
    clipped_channels: list[int]
    listening: list[int] = []
    dead_channels: list[int] = []
    low_snr_channels: list[int] = []


class CheckerboardEvent(_Event):
    type: Literal["checkerboard"] = "checkerboard"
    step: str
    camera: str
    found: bool


class WarningEvent(_Event):
    type: Literal["warning"] = "warning"
    step: str | None = None
    check: str | None = None
    message: str


class ErrorEvent(_Event):
    type: Literal["error"] = "error"
    step: str | None = None
    message: str


class CaptureEvent(_Event):
    """A capture of a step ended: its attempt completed or was abandoned (and why)."""

    type: Literal["capture"] = "capture"
    step: str
    outcome: Literal["complete", "abandoned"]
    reason: str = ""


class WorkerEvent(_Event):
    """A calibration worker joined, left, or was declared dead (silent too long)."""

    type: Literal["worker"] = "worker"
    worker: str
    state: Literal["joined", "left", "lost"]
    reason: str = ""


class JobEvent(_Event):
    """A calibration job changed state; `failed` carries the worker's error for a person."""

    type: Literal["job"] = "job"
    job_id: str
    kind: str
    state: Literal["queued", "leased", "running", "requeued", "done", "failed", "superseded"]
    attempt: int
    worker: str | None = None
    reason: str = ""


class LiveCalibrationEvent(_Event):
    """The calibration of the poses captured so far (see LiveUpdate)."""

    type: Literal["live_calibration"] = "live_calibration"
    job_id: str
    update: LiveUpdate


class CalibrationEvent(_Event):
    """A session's final calibration is stored beside it."""

    type: Literal["calibration"] = "calibration"
    job_id: str
    attempt: int
    worker: str
    path: str = Field(description="result.json in the session's calibration directory")
    sha256: str
    n_microphones: int
    mean_std_m: float = Field(description="mean over microphones of the position std norm")
    speed_of_sound_m_s: float


Event = Annotated[
    StateEvent | InstructionEvent | ProgressEvent | LevelsEvent | CheckerboardEvent
    | WarningEvent | ErrorEvent | CaptureEvent | WorkerEvent | JobEvent | LiveCalibrationEvent
    | CalibrationEvent | PreviewEvent | LiveModeEvent | LiveFrameEvent
    | LiveRecordedEvent,
    Field(discriminator="type"),
]
EVENT_ADAPTER: TypeAdapter[Event] = TypeAdapter(Event)
EVENT_TOPICS: tuple[str, ...] = tuple(
    t.model_fields["type"].default for t in get_args(get_args(Event)[0]))
"""Every event type, each the topic of its events (a subscriber may choose among them)."""
PREVIEW_TOPIC = "preview"
"""Previews are large (kilobytes each, a few a second): clients that do not draw them leave
this topic out of their subscription (`DaemonClient.subscribe`), and the publisher drops them."""
LIVE_FRAME_TOPIC = "live_frame"
"""Live camera frames: large like previews, left out unless asked for."""
SAMPLES_TOPIC = "samples"
"""Live mode's time data: not JSON events but three frames (`SamplesHeader`), on a topic no
event topic is a prefix of, so that subscribers to the events never receive them."""
REQUEST_ADAPTER: TypeAdapter[Request] = TypeAdapter(Request)


class SamplesHeader(_Message):
    """The second frame of a `samples` message; the third is the codes, int16 little-endian,
    (n_samples, n_columns) row-major, the columns of `describe`."""

    v: Literal[2] = PROTOCOL_VERSION
    start: int = Field(ge=0, description="stream index of the first row")
    n_samples: int = Field(gt=0)
    n_columns: int = Field(gt=0)
    sample_rate_hz: float = Field(gt=0)
    monotonic_s: float = Field(description="the daemon host's monotonic clock when the first "
                                           "row was scanned (by the clock live mode reads by)")


def utc_now() -> datetime:
    return datetime.now(UTC)


def json_schemas() -> dict[str, dict]:
    """JSON Schemas of every message, by file stem, for consumers in any language."""
    return {
        "request": REQUEST_ADAPTER.json_schema(),
        "reply": Reply.model_json_schema(),
        "event": EVENT_ADAPTER.json_schema(),
        "status-result": StatusResult.model_json_schema(),
        "sessions-result": SessionsResult.model_json_schema(),
        "capture-result": CaptureResult.model_json_schema(),
        "describe-result": DescribeResult.model_json_schema(),
        "live-record-result": LiveRecordResult.model_json_schema(),
        "samples-header": SamplesHeader.model_json_schema(),
        "session-report-result": SessionReportResult.model_json_schema(),
        "session-file-result": SessionFileResult.model_json_schema(),
        **job_schemas(),
    }
