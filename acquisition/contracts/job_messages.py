"""The calibration hand-off on the wire: jobs, heartbeats, results and file chunks (version 2:
the live update gained the suggestion's outline in camera 0's image and the poses taken).

Two sockets, both bound by the daemon (ROUTER) and connected to by each worker (DEALER):

- jobs: the chatty, self-describing dialog. A worker says `ready`, gets at most one `job`,
  reports `progress` and `live` updates, and ends with `done` (the result bytes in a second
  frame) or `failed`. Both sides send `heartbeat` when they have nothing else to say; any
  message counts as a sign of life (zguide ch.4, Paranoid Pirate).
- files: the terse data flow. A worker asks for `fetch` (a byte range of one file of its job)
  and gets a `chunk` (the bytes in a second frame) or a `fetch_error`. The worker keeps a few
  requests in flight (credit-based flow control, zguide ch.7), so no high-water mark matters.

Every message is one frame of JSON (plus the data frame of `done` and `chunk`), validated by
pydantic on both ends. Its `v` is read first (`version_problem`): a message of another protocol
version, or with none, is refused with a reason the peer can log (`refused` on the jobs socket,
`fetch_error` on the files socket), never read as this version. Every id and path is a safe
name or relative path (acquisition.safe_names). This module is light (pydantic only) because
workers on machines without boards import it. docs/protocol.md documents the exchange.
"""

from __future__ import annotations

import json
from typing import Annotated, Final, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from acquisition.contracts.safe_names import SafeName, SafeRelativePath

JOB_PROTOCOL_VERSION: Final = 2

JobKind = Literal["live", "final"]
"""live: the calibration so far, after a pose (fast, no joint fit); final: the full calibration
of a closed session, stored beside it as calibration/result.json."""

Sha256 = Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]
RelPath = SafeRelativePath
"""A session-relative path: it names a file on the daemon's disk and in the worker's cache."""
JobId = SafeName
"""A job id or a session id: each names a file or a directory (outbox, cache)."""
PersonName = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[^\x00-\x1f\x7f]+$")]
"""A name shown to people (in logs and events): no control characters."""


class _Msg(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    v: Literal[2] = JOB_PROTOCOL_VERSION


class JobFile(_Msg):
    """One file the job needs, as the session's journal records it."""

    path: RelPath
    bytes: int = Field(ge=0)
    sha256: Sha256


class JournalPrefix(_Msg):
    """The journal up to the job's point: the first `bytes` bytes of journal.jsonl (append-only,
    so this prefix never changes) and their checksum. A live job's prefix ends at the step_end
    of its last pose, so the worker's copy reads as an interrupted session of those poses."""

    bytes: int = Field(ge=1)
    sha256: Sha256


class LiveMicrophone(_Msg):
    id: int
    position_m: tuple[float, float, float]
    std_m: tuple[float, float, float]


Pixel = tuple[float, float]


class PoseSuggestion(_Msg):
    """Where one more rig pose would lower the predicted mean error most (camera-0 frame)."""

    distance_m: float = Field(description="from camera 0 to the rig's centre")
    direction: tuple[float, float, float] = Field(description="unit vector, camera-0 frame")
    azimuth_deg: float = Field(description="positive to the camera's right")
    elevation_deg: float = Field(description="positive upwards")
    predicted_accuracy_m: float = Field(description="predicted mean error with that pose added")
    outline_px: list[Pixel] = Field(
        default=[], max_length=4,
        description="the board's four outer corners at that pose in camera 0's image, pixels")
    speakers_px: list[Pixel] = Field(
        default=[], max_length=64, description="the rig's speakers there, pixels of camera 0")


class PoseTaken(_Msg):
    """A pose the live calibration used: where the rig's centre was, from camera 0."""

    step: SafeRelativePath
    distance_m: float
    azimuth_deg: float = Field(description="positive to the camera's right")
    elevation_deg: float = Field(description="positive upwards")


class LiveUpdate(_Msg):
    """The calibration so far, published after each pose (see calibration.worker.live)."""

    session_id: JobId
    poses: int = Field(description="poses used")
    microphones: list[LiveMicrophone]
    mean_uncertainty_m: float = Field(
        description="mean over microphones of E|error| from the fit's covariance")
    predicted_accuracy_m: float = Field(
        description="mean E|error| the Cramer-Rao bound predicts from these poses")
    speed_of_sound_m_s: float
    suggestion: PoseSuggestion | None = None
    image_size: tuple[int, int] | None = Field(
        default=None, description="camera 0's image (width, height), pixels: the frame of the "
                                  "suggestion's pixels")
    poses_taken: list[PoseTaken] = Field(default=[], max_length=10_000)


# -- worker -> daemon, jobs socket -------------------------------------------------------------


class Ready(_Msg):
    type: Literal["ready"] = "ready"
    worker: PersonName = Field(description="a name for people")


class Heartbeat(_Msg):
    type: Literal["heartbeat"] = "heartbeat"


class Progress(_Msg):
    type: Literal["progress"] = "progress"
    job_id: JobId
    attempt: int = Field(ge=1)
    stage: str = Field(max_length=64)


class Live(_Msg):
    type: Literal["live"] = "live"
    job_id: JobId
    attempt: int = Field(ge=1)
    update: LiveUpdate


MAX_REPORT_FILES = 16
"""The most report files (report.md and its figures) a `done` message carries."""
ReportName = Annotated[str, Field(pattern=r"^[a-z0-9_]{1,40}\.(md|png)$")]
"""A report file's name: a plain name, Markdown or PNG only (stored beside result.json)."""


class ReportFile(_Msg):
    """One file of the report the worker wrote beside its result (calibration.report)."""

    name: ReportName
    sha256: Sha256


class Done(_Msg):
    """A final job's result; the result.json bytes follow in the second frame, then one frame
    per file of `report`, in its order (report.md and its figures, as `micam calibrate`
    writes them), to be stored beside result.json."""

    type: Literal["done"] = "done"
    job_id: JobId
    attempt: int = Field(ge=1)
    result_sha256: Sha256
    report: list[ReportFile] = Field(default=[], max_length=MAX_REPORT_FILES)


class Failed(_Msg):
    type: Literal["failed"] = "failed"
    job_id: JobId
    attempt: int = Field(ge=1)
    reason: str = Field(max_length=4000)
    retryable: bool = Field(description="another attempt (maybe on another worker) may succeed")


class WorkerError(_Msg):
    """The worker could not read a message from the daemon (no job id to answer with)."""

    type: Literal["error"] = "error"
    reason: str = Field(max_length=4000)


class Bye(_Msg):
    type: Literal["bye"] = "bye"


WorkerMessage = Annotated[Ready | Heartbeat | Progress | Live | Done | Failed | WorkerError | Bye,
                          Field(discriminator="type")]
WORKER_MESSAGE: TypeAdapter[WorkerMessage] = TypeAdapter(WorkerMessage)


# -- daemon -> worker, jobs socket -------------------------------------------------------------


class Job(_Msg):
    """One job for one worker; `(job_id, attempt)` fences its results."""

    type: Literal["job"] = "job"
    job_id: JobId
    attempt: int = Field(ge=1, description="1 for the first lease, +1 for every re-lease")
    kind: JobKind
    session_id: JobId
    poses: int = Field(ge=0, description="completed poses the job covers")
    journal: JournalPrefix
    files: list[JobFile]


class Ack(_Msg):
    """The daemon's answer to done/failed/live: whether it counted (stale attempts do not)."""

    type: Literal["ack"] = "ack"
    job_id: JobId
    attempt: int
    accepted: bool
    reason: str = ""


class Refused(_Msg):
    """The daemon could not read a worker's message (another protocol version, no version, not
    a message of this protocol): why, for the worker's log."""

    type: Literal["refused"] = "refused"
    reason: str


class Reconnect(_Msg):
    """The daemon does not know this worker (it restarted, or declared it dead): say ready."""

    type: Literal["reconnect"] = "reconnect"
    reason: str


DaemonMessage = Annotated[Job | Heartbeat | Ack | Reconnect | Refused,
                          Field(discriminator="type")]
DAEMON_MESSAGE: TypeAdapter[DaemonMessage] = TypeAdapter(DaemonMessage)


# -- files socket ------------------------------------------------------------------------------


FETCH_WINDOW = 8
"""Fetches a worker keeps in flight at most (each answered by one reply): what the two sides'
queues of file replies are sized by."""


class Fetch(_Msg):
    """Bytes [offset, offset + length) of `path` (a file of job `job_id`, or journal.jsonl)."""

    type: Literal["fetch"] = "fetch"
    job_id: JobId
    path: RelPath
    offset: int = Field(ge=0)
    length: int = Field(ge=1, le=4 * 2**20)


class Chunk(_Msg):
    """The bytes asked for follow in the second frame (fewer only at the end of the file)."""

    type: Literal["chunk"] = "chunk"
    path: str
    offset: int


class FetchError(_Msg):
    type: Literal["fetch_error"] = "fetch_error"
    path: str
    reason: str


FileReply = Annotated[Chunk | FetchError, Field(discriminator="type")]
FILE_REPLY: TypeAdapter[FileReply] = TypeAdapter(FileReply)
FETCH: TypeAdapter[Fetch] = TypeAdapter(Fetch)


def encode(message: BaseModel) -> bytes:
    return message.model_dump_json().encode()


def version_problem(frame: bytes) -> str | None:
    """Why `frame` is not a message of this protocol version, or None if its `v` is ours (or
    it is not a JSON object at all: validation then says what it is)."""
    try:
        data = json.loads(frame)
    except (ValueError, RecursionError):
        return None
    if not isinstance(data, dict):
        return None
    if "v" not in data:
        return (f"the message carries no protocol version `v`; this side speaks version "
                f"{JOB_PROTOCOL_VERSION} of the job protocol and reads nothing unversioned")
    version = data["v"]
    if version != JOB_PROTOCOL_VERSION or isinstance(version, bool):
        shown = str(version)[:20] if isinstance(version, int | float | str) else "a " + type(
            version).__name__
        return (f"job protocol version {shown} is not supported; this side "
                f"speaks version {JOB_PROTOCOL_VERSION}: run micam versions that match")
    return None


def job_schemas() -> dict[str, dict]:
    """JSON Schemas of the hand-off's messages, by file stem."""
    return {
        "worker-message": WORKER_MESSAGE.json_schema(),
        "daemon-message": DAEMON_MESSAGE.json_schema(),
        "fetch": Fetch.model_json_schema(),
        "file-reply": FILE_REPLY.json_schema(),
        "live-update": LiveUpdate.model_json_schema(),
    }
