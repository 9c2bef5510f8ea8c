"""The append-only journal: durable appends, tolerant reading, and replay into a session state.

The journal is the session's source of truth. Each record is one JSON line written with a single
`write` and fsync'd before the call returns, so a crash can damage at most the last line, and
only by cutting it short: what a crash leaves is a final piece without its newline. The reader
ignores that torn tail, unless the session was stopped (no append follows `session_stop`), and
refuses every other damage, naming its line: a line that ends in its newline and is not a valid
record, anything after `session_stop`. `SessionState` replays the records and enforces the rules
of the format (consecutive `seq`, one open attempt at a time, nothing after `session_stop`), so
the writer and the reader share one interpretation.

A journal comes from a directory any account may have written, so its sizes are bounded before
they cost memory: the file's size is checked before it is read, and each line is read with a
ceiling (MAX_RECORD_BYTES), never whole. The writer refuses to exceed the same bounds, so every
journal it writes can be read back.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from pydantic import ValidationError

from ..safe_names import is_name
from ._atomic import fsync_dir
from ._layout import attempt_dir
from ._models import (
    RECORD_ADAPTER,
    SCHEMA_VERSION,
    FileRecord,
    FileWritten,
    Record,
    SessionError,
    SessionManifest,
    SessionResume,
    SessionStart,
    SessionStatus,
    SessionStop,
    StepAbandoned,
    StepBegin,
    StepEnd,
    StepRecord,
)

JOURNAL_NAME = "journal.jsonl"
MAX_RECORD_BYTES = 2**20
"""Longest journal line, bytes with its newline (1 MiB). The largest records are a
`session_start` with its capture configuration and a `file` record with per-channel meta, some
kilobytes to a few tens of kilobytes for 1024 channels."""
MAX_JOURNAL_BYTES = 256 * 2**20
"""Largest journal, bytes (256 MiB): a few hundred thousand records, where a session of a
thousand poses journals a few thousand."""


@dataclass(frozen=True)
class JournalScan:
    """The valid records of a journal, and where its valid part ends.

    Attributes:
        records: every record up to the last complete, valid line.
        valid_bytes: length of the journal up to and including that line's newline.
        torn_tail: True if something followed (a line cut short by a crash), which was ignored.
    """

    records: list[Record]
    valid_bytes: int
    torn_tail: bool


def journal_path(session: Path) -> Path:
    """The journal file of the session directory `session`."""
    return session / JOURNAL_NAME


def scan_journal(path: Path) -> JournalScan:
    """Parse a journal file, ignoring a torn last line (see the module docstring) and refusing
    any other damage, naming its line."""
    try:
        with path.open("rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size > MAX_JOURNAL_BYTES:
                raise SessionError(
                    f"{path} is {size} bytes, more than the {MAX_JOURNAL_BYTES} a journal may "
                    "hold: it was altered, or is not a micam journal; do not resume it"
                )
            return _scan_lines(path, fh)
    except FileNotFoundError:
        raise SessionError(
            f"{path.parent} is not a micam session: it has no {JOURNAL_NAME}; "
            "pass a directory made by SessionWriter.create"
        ) from None
    except OSError as exc:
        raise SessionError(f"cannot read the journal {path}: {exc}") from exc


def _scan_lines(path: Path, fh: BinaryIO) -> JournalScan:
    """The records of an open journal, read line by line, no line longer than MAX_RECORD_BYTES."""
    records: list[Record] = []
    valid_bytes = 0
    number = 0
    while line := fh.readline(MAX_RECORD_BYTES + 1):
        number += 1
        complete = line.endswith(b"\n")
        if len(line) > MAX_RECORD_BYTES:
            raise _damaged(path, number, f"longer than {MAX_RECORD_BYTES} bytes, the longest "
                                         "record the writer writes")
        stopped = bool(records) and isinstance(records[-1], SessionStop)
        if stopped:
            raise _damaged(path, number, "it follows session_stop, after which the writer "
                                         "appends nothing")
        if not complete:  # the last piece, without its newline: what a crash leaves
            return JournalScan(records, valid_bytes, torn_tail=True)
        try:
            records.append(RECORD_ADAPTER.validate_json(line))
        except ValidationError as exc:
            raise _damaged(path, number, f"not a valid journal record ({_first_error(exc)})"
                           ) from exc
        valid_bytes += len(line)
    return JournalScan(records, valid_bytes, torn_tail=False)


def _damaged(path: Path, number: int, what: str) -> SessionError:
    return SessionError(
        f"{path}, line {number}: {what}. A crash only cuts the last line short, so this "
        "journal was altered or its disk is failing: do not resume it; restore it from a backup "
        "or recover its files by hand"
    )


def _first_error(exc: ValidationError) -> str:
    error = exc.errors()[0]
    where = ".".join(str(part) for part in error["loc"])
    return f"{where}: {error['msg']}" if where else error["msg"]


def journal_records(path: Path) -> list[Record]:
    """The valid records of a session's journal; `path` is the session directory or the journal."""
    return scan_journal(journal_path(path) if path.is_dir() else path).records


@dataclass
class OpenAttempt:
    """An attempt that has begun and not yet ended, with the files journaled so far."""

    step: str
    attempt: int
    dir: str
    files: dict[str, FileRecord] = field(default_factory=dict)


class SessionState:
    """What a journal says: completed steps, the open attempt, attempt counts, the stop record."""

    def __init__(self, start: SessionStart) -> None:
        if start.seq != 0:
            raise SessionError(f"record seq {start.seq}: session_start must be the first record")
        if start.schema_version != SCHEMA_VERSION:
            raise SessionError(
                f"schema version {start.schema_version} is not supported (this micam reads "
                f"version {SCHEMA_VERSION}); open the session with the micam that wrote it"
            )
        self.start = start
        self.completed: dict[str, StepRecord] = {}
        self.open: OpenAttempt | None = None
        self.last_attempt: dict[str, int] = {}
        self.stop: SessionStop | None = None
        self.next_seq = 1

    @classmethod
    def replay(cls, records: Sequence[Record]) -> SessionState:
        """Rebuild the state from journal records, checking every rule of the format."""
        if not records or not isinstance(records[0], SessionStart):
            raise SessionError("the journal does not begin with a session_start record")
        state = cls(records[0])
        for record in records[1:]:
            state.apply(record)
        return state

    @property
    def status(self) -> SessionStatus:
        """The status a reader reports: without a stop record a session is interrupted."""
        if self.stop is None:
            return "interrupted"
        return "complete" if self.stop.exit_status == "success" else self.stop.exit_status

    def manifest(self, status: SessionStatus) -> SessionManifest:
        """The manifest summarising this state, with the given status."""
        return SessionManifest(
            session_id=self.start.session_id,
            created_utc=self.start.time_utc,
            capture=self.start.capture,
            status=status,
            steps=dict(self.completed),
        )

    def check(self, record: Record) -> None:
        """Raise SessionError if `record` may not follow the records applied so far."""
        problem = self._problem(record)
        if problem:
            raise SessionError(f"record seq {record.seq} ({record.kind}): {problem}")

    def _problem(self, record: Record) -> str | None:
        if record.seq != self.next_seq:
            return f"expected seq {self.next_seq}"
        if self.stop is not None:
            return "no record may follow session_stop"
        match record:
            case SessionStart():
                return "a journal holds one session_start only"
            case StepBegin(step=step, attempt=attempt, dir=directory):
                if directory != attempt_dir(step, attempt):
                    return f"its directory {directory!r} is not {attempt_dir(step, attempt)!r}"
                if self.open is not None:
                    return f"step {self.open.step!r} attempt {self.open.attempt} is still open"
                if step in self.completed:
                    return f"step {step!r} is already completed"
                if attempt <= self.last_attempt.get(step, 0):
                    return f"attempt {attempt} of step {step!r} was used before"
            case FileWritten() | StepEnd() | StepAbandoned():
                if self.open is None or (self.open.step, self.open.attempt) != (
                    record.step,
                    record.attempt,
                ):
                    return f"step {record.step!r} attempt {record.attempt} is not open"
                if isinstance(record, FileWritten):
                    folder, _, name = record.path.rpartition("/")
                    if folder != self.open.dir or not is_name(name):
                        return f"{record.path} is not a file of the attempt's {self.open.dir}/"
                    if name in self.open.files:
                        return f"{record.path} is journaled twice"
            case SessionResume() | SessionStop():
                if self.open is not None:
                    return f"step {self.open.step!r} attempt {self.open.attempt} is still open"
        return None

    def apply(self, record: Record) -> None:
        """Check `record` and update the state with it."""
        self.check(record)
        self.next_seq += 1
        match record:
            case StepBegin(step=step, attempt=attempt, dir=directory):
                self.open = OpenAttempt(step, attempt, directory)
                self.last_attempt[step] = attempt
            case FileWritten():
                assert self.open is not None
                self.open.files[_file_name(record)] = FileRecord(
                    path=record.path,
                    sha256=record.sha256,
                    bytes=record.bytes,
                    role=record.role,
                    meta=record.meta,
                )
            case StepEnd():
                assert self.open is not None
                self.completed[record.step] = StepRecord(
                    step=record.step,
                    attempt=record.attempt,
                    dir=self.open.dir,
                    files=self.open.files,
                )
                self.open = None
            case StepAbandoned():
                self.open = None
            case SessionStop():
                self.stop = record


def _file_name(record: FileWritten) -> str:
    return record.path.rsplit("/", 1)[-1]


def load_state(session: Path) -> tuple[SessionState, JournalScan]:
    """Read and replay a session's journal; errors name the journal file."""
    path = journal_path(session)
    scan = scan_journal(path)
    if not scan.records:
        raise SessionError(
            f"{path} holds no complete record: the session's creation was interrupted before it "
            "started; SessionWriter.create may reuse the directory"
        )
    try:
        return SessionState.replay(scan.records), scan
    except SessionError as exc:
        raise SessionError(f"{path}: {exc}") from exc


# The journal writers open in this process, by (device, inode) of their journal file.
_OPEN_WRITERS: dict[tuple[int, int], JournalWriter] = {}


class JournalWriter:
    """Appends records to a journal durably; one writer per journal at a time.

    Across processes an exclusive flock enforces that (the kernel releases it when the process
    dies, so a crash never leaves it behind). Within one process a new writer takes the journal
    over and closes the earlier one, which is what a resume after an in-process failure needs;
    the earlier writer is then `superseded` and refuses further use.
    """

    def __init__(self, path: Path, *, create: bool) -> None:
        flags = os.O_WRONLY | os.O_APPEND | (os.O_CREAT | os.O_EXCL if create else 0)
        self.path = path
        self.superseded = False
        self._fd: int | None = os.open(path, flags, 0o644)
        stat = os.fstat(self._fd)
        self._key = (stat.st_dev, stat.st_ino)
        earlier = _OPEN_WRITERS.get(self._key)
        if earlier is not None:
            earlier.close()
            earlier.superseded = True
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.close()
            raise SessionError(
                f"{path} is locked by another process recording into this session; stop that "
                "process or let it finish first"
            ) from None
        _OPEN_WRITERS[self._key] = self
        if create:
            fsync_dir(path.parent)

    @property
    def closed(self) -> bool:
        return self._fd is None

    def truncate(self, size: int) -> None:
        """Cut the journal to `size` bytes (drops a torn last line before appending again)."""
        os.ftruncate(self._require_fd(), size)
        os.fsync(self._require_fd())

    def append(self, record: Record) -> None:
        """Write one record as one line and fsync it; it is durable when this returns."""
        fd = self._require_fd()
        line = record.model_dump_json().encode() + b"\n"
        if len(line) > MAX_RECORD_BYTES:
            raise SessionError(
                f"a {record.kind} record of {len(line)} bytes is longer than the "
                f"{MAX_RECORD_BYTES} a journal line may hold (readers refuse longer lines); "
                "keep the capture configuration and the files' meta smaller"
            )
        if os.fstat(fd).st_size + len(line) > MAX_JOURNAL_BYTES:
            raise SessionError(
                f"{self.path} would grow beyond the {MAX_JOURNAL_BYTES} bytes a journal may "
                "hold (readers refuse larger ones); stop this session and record the rest "
                "in a new one"
            )
        remaining = memoryview(line)
        while remaining:
            remaining = remaining[os.write(fd, remaining) :]
        os.fsync(fd)

    def close(self) -> None:
        """Close the journal and release its lock; harmless when already closed."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
            if _OPEN_WRITERS.get(self._key) is self:
                del _OPEN_WRITERS[self._key]

    def _require_fd(self) -> int:
        if self._fd is None:
            raise SessionError(f"{self.path} is closed")
        return self._fd
