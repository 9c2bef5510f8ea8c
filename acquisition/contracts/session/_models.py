"""The session store's error, its journal records and its manifest, as pydantic models.

The journal records are the contract between acquisition and calibration (see
docs/session-format.md): one model per `kind`, read back through the `Record` discriminated
union. Every model forbids unknown fields so that a damaged or foreign line is detected instead of
silently half-read, and every id and path in a record is held to the grammar of
`acquisition.safe_names`, so that an edited journal cannot point outside its session (the replay
in _journal.py also checks that each path is the one the writer would have used).
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Final, Literal

from pydantic import AfterValidator, AwareDatetime, BaseModel, ConfigDict, Field, TypeAdapter

from ..errors import UserError
from ..safe_names import SafeName, SafeRelativePath, is_step_id

SCHEMA_VERSION: Final = 1

FileRole = Literal["recording", "image", "other"]
ExitStatus = Literal["success", "aborted", "failed"]
SessionStatus = Literal["open", "complete", "aborted", "failed", "interrupted"]


def _step_id(text: str) -> str:
    if not is_step_id(text):
        raise ValueError("a step id is 'name' or 'group/name' of letters, digits, '_', '.', '-'")
    return text


StepId = Annotated[str, AfterValidator(_step_id)]
Sha256 = Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]


class SessionError(UserError):
    """A session directory cannot be created, written, resumed or read as asked.

    The message names the session, step or file concerned and says what to do about it.
    """


class SessionExistsError(SessionError):
    """A new session was asked for in a directory that already holds one (which is never
    overwritten). Command-line tools catch it to suggest their own way of resuming."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class _RecordBase(_Model):
    """Fields every journal record carries: its position in the journal and when it was written."""

    seq: int = Field(ge=0)
    time_utc: AwareDatetime


class SessionStart(_RecordBase):
    """First record of every journal. Holds the capture configuration so the journal suffices."""

    kind: Literal["session_start"] = "session_start"
    session_id: SafeName
    schema_version: int
    capture: dict[str, Any]


class StepBegin(_RecordBase):
    """A new attempt at a step began; its files go to `dir` (relative to the session)."""

    kind: Literal["step_begin"] = "step_begin"
    step: StepId
    attempt: int = Field(ge=1)
    dir: SafeRelativePath


class FileWritten(_RecordBase):
    """A file of the open attempt reached its final name, durably; `path` is session-relative."""

    kind: Literal["file"] = "file"
    step: StepId
    attempt: int = Field(ge=1)
    path: SafeRelativePath
    sha256: Sha256
    bytes: int = Field(ge=0)
    role: FileRole
    meta: dict[str, Any]


class StepEnd(_RecordBase):
    """The attempt completed: from this record on, the step counts as done with this attempt."""

    kind: Literal["step_end"] = "step_end"
    step: StepId
    attempt: int = Field(ge=1)


class StepAbandoned(_RecordBase):
    """The attempt will never complete (a retry, a crash found on resume, or a stop)."""

    kind: Literal["step_abandoned"] = "step_abandoned"
    step: StepId
    attempt: int = Field(ge=1)
    reason: str


class SessionResume(_RecordBase):
    """A writer reopened the session after it was interrupted."""

    kind: Literal["session_resume"] = "session_resume"


class SessionStop(_RecordBase):
    """Last record of a closed session; nothing may follow it."""

    kind: Literal["session_stop"] = "session_stop"
    exit_status: ExitStatus
    reason: str


Record = Annotated[
    SessionStart | StepBegin | FileWritten | StepEnd | StepAbandoned | SessionResume | SessionStop,
    Field(discriminator="kind"),
]
RECORD_ADAPTER: TypeAdapter[Record] = TypeAdapter(Record)


class FileRecord(_Model):
    """One journaled file of a step: where it is, its checksum and size, and what it holds."""

    path: str
    sha256: str
    bytes: int
    role: FileRole
    meta: dict[str, Any]


class StepRecord(_Model):
    """A completed step: the attempt that completed it and that attempt's files, by file name."""

    step: str
    attempt: int
    dir: str
    files: dict[str, FileRecord]


class SessionManifest(_Model):
    """The readable summary in manifest.json, rebuilt from the journal (the source of truth)."""

    schema_version: Literal[1] = SCHEMA_VERSION
    session_id: str
    created_utc: datetime
    capture: dict[str, Any]
    status: SessionStatus
    steps: dict[str, StepRecord]
