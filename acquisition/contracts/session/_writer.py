"""SessionWriter: creates a session, records steps attempt by attempt, resumes after a crash.

Every change follows one order: make the file durable under its final name first, then journal
it. A crash therefore leaves at worst an unjournaled file in an attempt that never ended; resume
marks that attempt abandoned and the next attempt gets a fresh directory, so nothing completed is
ever overwritten.
"""

from __future__ import annotations

import copy
import io
import json
import operator
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, BinaryIO

import cv2
import numpy as np
import soundfile as sf

from daq import ClosesOnExit

from ..media_headers import MAX_IMAGE_PIXELS, MAX_RECORDING_VALUES
from ..output_paths import dangling_link_problem
from ..safe_names import is_name, is_step_id
from ._atomic import PARTIAL_SUFFIX, fsync_dir, make_dirs, remove_partials, write_atomic
from ._journal import JournalWriter, SessionState, journal_path, load_state, scan_journal
from ._layout import attempt_dir
from ._models import (
    SCHEMA_VERSION,
    ExitStatus,
    FileRole,
    FileWritten,
    Record,
    SessionError,
    SessionExistsError,
    SessionManifest,
    SessionResume,
    SessionStart,
    SessionStatus,
    SessionStop,
    StepAbandoned,
    StepBegin,
    StepEnd,
)

MANIFEST_NAME = "manifest.json"
MAX_CHANNELS = 1024  # libsndfile's limit for every container
# Plain WAV sizes are 32-bit; larger recordings go to RF64 (the reader detects the container).
WAV_MAX_DATA_BYTES = 0xFFFF_FFFF - 1024

_EXIT_STATUSES: tuple[ExitStatus, ...] = ("success", "aborted", "failed")


def _utc_now() -> datetime:
    return datetime.now(UTC)


def _json_copy(value: Any, what: str) -> Any:
    """A deep copy of `value` as JSON gives it back; refuses what JSON cannot hold exactly."""
    try:
        return json.loads(json.dumps(value, allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise SessionError(
            f"{what} must be JSON-serialisable without NaN or infinity ({exc}); "
            "convert numpy values with .item() or .tolist()"
        ) from exc


def _check_step_id(step: str) -> None:
    if not is_step_id(step):
        raise SessionError(
            f"invalid step id {step!r}: use 'name' or 'group/name' made of letters, digits, "
            "'_', '.', '-' (e.g. 'refmic', 'reference/4', 'pose/0003')"
        )


def _check_file_name(name: str, suffix: str) -> None:
    if (
        not isinstance(name, str)
        or not is_name(name)
        or not name.endswith(suffix)
        or name.endswith(PARTIAL_SUFFIX)
    ):
        raise SessionError(
            f"invalid file name {name!r}: use a plain name ending in {suffix!r} made of letters, "
            "digits, '_', '.', '-' (no directories)"
        )


def _check_codes(codes: np.ndarray, name: str) -> None:
    if not isinstance(codes, np.ndarray) or codes.dtype != np.int16:
        got = codes.dtype if isinstance(codes, np.ndarray) else type(codes).__name__
        raise SessionError(
            f"recording {name!r}: codes must be a numpy int16 array of raw ADC codes, got {got}; "
            "store the codes as read from the boards (the volts-per-code scale belongs in the "
            "capture configuration)"
        )
    if codes.ndim != 2:
        raise SessionError(
            f"recording {name!r}: codes must have shape (n_samples, n_channels), got shape "
            f"{codes.shape}; for a single channel pass codes[:, np.newaxis]"
        )
    n_samples, n_channels = codes.shape
    if n_samples == 0 or not 1 <= n_channels <= MAX_CHANNELS or codes.size > MAX_RECORDING_VALUES:
        raise SessionError(
            f"recording {name!r}: shape {codes.shape} is not storable; a recording needs at least "
            f"one sample, 1 to {MAX_CHANNELS} channels and at most {MAX_RECORDING_VALUES} "
            "samples x channels (what readers decode)"
        )


def _check_image(image: np.ndarray, name: str) -> None:
    if (
        not isinstance(image, np.ndarray)
        or image.dtype != np.uint8
        or not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3))
        or image.size == 0
        or image.shape[0] * image.shape[1] > MAX_IMAGE_PIXELS
    ):
        got = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image)
        raise SessionError(
            f"image {name!r}: expected a uint8 array, (height, width) grey or (height, width, 3) "
            f"BGR of at most {MAX_IMAGE_PIXELS} pixels, got {got}"
        )


def _reserve_meta(meta: dict | None, own: dict[str, Any], name: str) -> dict[str, Any]:
    """The caller's meta plus the store's own fields, refusing a caller key that clashes."""
    meta = _json_copy(meta or {}, f"meta of {name!r}")
    if not isinstance(meta, dict):
        raise SessionError(f"meta of {name!r} must be a dict, got {type(meta).__name__}")
    clash = sorted(set(meta) & set(own))
    if clash:
        raise SessionError(
            f"meta of {name!r} may not set {clash}: the session store fills them in itself"
        )
    return {**meta, **own}


class SessionWriter(ClosesOnExit):
    """Writes one session directory. Get one with `create` or `resume`, never directly.

    Steps are recorded one attempt at a time: `begin_step`, the `write_*` calls, then `end_step`
    (or `abandon_step` to retry). `stop` closes the session for good; `close` only releases it,
    leaving it interrupted and resumable. A writer holds an exclusive lock on the journal.
    """

    def __init__(self, path: Path, journal: JournalWriter, state: SessionState) -> None:
        self._path = path
        self._journal = journal
        self._state = state

    # -- opening ------------------------------------------------------------------------------

    @classmethod
    def create(cls, path: Path, capture: dict, session_id: str | None = None) -> SessionWriter:
        """Start a new session in `path`, which must not exist or be an empty directory.

        `capture` is the frozen capture configuration (channel map, volts-per-code scales, rates,
        ...); it is stored in the journal's first record and in the manifest.
        """
        path = Path(path)
        if not isinstance(capture, dict):
            raise SessionError(f"capture must be a dict, got {type(capture).__name__}")
        capture = _json_copy(capture, "the capture configuration")
        session_id = session_id or f"{_utc_now():%Y-%m-%dT%H-%M-%SZ}_{uuid.uuid4().hex[:8]}"
        if not is_name(session_id):
            raise SessionError(
                f"invalid session id {session_id!r}: use letters, digits, '_', '.', '-'"
            )
        cls._claim_directory(path)
        journal = JournalWriter(journal_path(path), create=True)
        start = SessionStart(
            seq=0,
            time_utc=_utc_now(),
            session_id=session_id,
            schema_version=SCHEMA_VERSION,
            capture=capture,
        )
        try:
            journal.append(start)
        except BaseException:
            journal.close()
            raise
        writer = cls(path, journal, SessionState(start))
        writer._write_manifest("open")
        return writer

    @staticmethod
    def _claim_directory(path: Path) -> None:
        """Make `path` the new session's directory, or say why it cannot be."""
        dangling = dangling_link_problem(path)
        if dangling:
            raise SessionError(f"{path} {dangling}")
        if not path.exists():
            make_dirs(path)
            return
        if not path.is_dir():
            raise SessionError(f"{path} is a file, not a directory; choose another session path")
        journal = journal_path(path)
        if journal.exists() and scan_journal(journal).records:
            raise SessionExistsError(
                f"{path} already holds a session; use SessionWriter.resume to continue it"
            )
        if any(entry != journal for entry in path.iterdir()):
            raise SessionError(f"{path} is not empty; create the session in a new directory")
        if journal.exists():  # left by a create that crashed before its first record
            journal.unlink()
            fsync_dir(path)

    @classmethod
    def resume(cls, path: Path) -> SessionWriter:
        """Reopen an interrupted session to record its remaining steps.

        Drops a torn last journal line, deletes `*.partial` files, journals every begun but
        unended attempt as abandoned (its files stay, unused), then journals session_resume.
        A closed session is refused, after the same tidying and a rewrite of its manifest
        (which a crash during `stop` may have left stale).
        """
        path = Path(path)
        if not journal_path(path).is_file():
            raise SessionError(
                f"{path} is not a micam session (it has no journal.jsonl); check the path, or "
                "use SessionWriter.create for a new session"
            )
        journal = JournalWriter(journal_path(path), create=False)
        try:
            state, scan = load_state(path)
            if scan.torn_tail:
                journal.truncate(scan.valid_bytes)
            remove_partials(path)
            if state.stop is not None:
                _write_manifest(path, state.manifest(state.status))  # in case stop was cut short
                raise SessionError(
                    f"{path} is closed (session_stop {state.stop.exit_status!r}); "
                    "start a new session instead"
                )
        except BaseException:
            journal.close()
            raise
        writer = cls(path, journal, state)
        writer._abandon_open("interrupted: found open when the session was resumed")
        writer._append(SessionResume(seq=state.next_seq, time_utc=_utc_now()))
        writer._write_manifest("open")
        return writer

    # -- properties -----------------------------------------------------------------------------

    @property
    def path(self) -> Path:
        """The session directory."""
        return self._path

    @property
    def session_id(self) -> str:
        return self._state.start.session_id

    @property
    def capture(self) -> dict:
        """A copy of the frozen capture configuration."""
        return copy.deepcopy(self._state.start.capture)

    def completed_steps(self) -> dict[str, int]:
        """Each completed step with the attempt that completed it."""
        return {step: record.attempt for step, record in self._state.completed.items()}

    # -- steps ----------------------------------------------------------------------------------

    def begin_step(self, step: str) -> int:
        """Open a new attempt at `step` in a fresh directory; return the attempt number."""
        self._require_writable()
        _check_step_id(step)
        if step in self._state.completed:
            raise SessionError(
                f"step {step!r} is already completed (attempt "
                f"{self._state.completed[step].attempt}) in {self._path}; a completed step is "
                "never recorded again"
            )
        if self._state.open is not None:
            raise SessionError(
                f"step {self._state.open.step!r} attempt {self._state.open.attempt} is still open; "
                f"end_step or abandon_step it before beginning {step!r}"
            )
        attempt = self._state.last_attempt.get(step, 0) + 1
        while (self._path / attempt_dir(step, attempt)).exists():
            attempt += 1  # a directory left by a crash before its step_begin: never reuse it
        directory = attempt_dir(step, attempt)
        make_dirs(self._path / directory)
        self._append(StepBegin(**self._stamp(), step=step, attempt=attempt, dir=directory))
        return attempt

    def end_step(self, step: str) -> None:
        """Complete the open attempt at `step`: from now on the step counts as done."""
        attempt = self._open_attempt(step)
        self._append(StepEnd(**self._stamp(), step=step, attempt=attempt))
        self._write_manifest("open")

    def abandon_step(self, step: str, reason: str) -> None:
        """Give up the open attempt at `step` (e.g. an overrun); `begin_step` may retry it.

        The attempt's files stay on disk but are never used.
        """
        attempt = self._open_attempt(step)
        self._append(StepAbandoned(**self._stamp(), step=step, attempt=attempt, reason=reason))

    # -- files ----------------------------------------------------------------------------------

    def write_recording(
        self,
        step: str,
        name: str,
        codes: np.ndarray,
        sample_rate_hz: int,
        meta: dict | None = None,
    ) -> Path:
        """Store raw int16 codes, shape (n_samples, n_channels), as 16-bit PCM WAV.

        `meta` gets `sample_rate_hz`, `n_samples`, `n_channels` and `container` added.
        """
        _check_file_name(name, ".wav")
        _check_codes(codes, name)
        try:
            rate = operator.index(sample_rate_hz)
        except TypeError:
            rate = 0
        if rate <= 0:
            raise SessionError(
                f"recording {name!r}: sample_rate_hz must be a positive integer, got "
                f"{sample_rate_hz!r}"
            )
        container = "WAV" if codes.nbytes <= WAV_MAX_DATA_BYTES else "RF64"
        own = {
            "sample_rate_hz": rate,
            "n_samples": codes.shape[0],
            "n_channels": codes.shape[1],
            "container": container,
        }
        full_meta = _reserve_meta(meta, own, name)
        data = np.ascontiguousarray(codes)

        def fill(fh: BinaryIO) -> None:
            # Encoded in memory first: libsndfile writing to a Python file would turn a full
            # disk into an AssertionError of soundfile's; fh.write raises the OSError itself.
            encoded = io.BytesIO()
            sf.write(encoded, data, rate, subtype="PCM_16", format=container)
            fh.write(encoded.getbuffer())

        return self._write_file(step, name, fill, "recording", full_meta)

    def write_image(
        self, step: str, name: str, image: np.ndarray, meta: dict | None = None
    ) -> Path:
        """Store a uint8 grey or BGR image as lossless PNG; `meta` gets width, height, channels."""
        _check_file_name(name, ".png")
        _check_image(image, name)
        own = {
            "width": image.shape[1],
            "height": image.shape[0],
            "channels": 1 if image.ndim == 2 else 3,
        }
        full_meta = _reserve_meta(meta, own, name)
        ok, encoded = cv2.imencode(".png", image)
        if not ok:
            raise SessionError(f"image {name!r}: OpenCV could not encode it as PNG")
        return self._write_file(
            step, name, lambda fh: fh.write(encoded.tobytes()), "image", full_meta
        )

    def write_json(self, step: str, name: str, data: dict) -> Path:
        """Store a small per-step record (pose data, board status, ...) as JSON."""
        _check_file_name(name, ".json")
        if not isinstance(data, dict):
            raise SessionError(f"{name!r}: data must be a dict, got {type(data).__name__}")
        text = json.dumps(_json_copy(data, f"data of {name!r}"), indent=2, sort_keys=True) + "\n"
        return self._write_file(step, name, lambda fh: fh.write(text.encode()), "other", {})

    # -- closing --------------------------------------------------------------------------------

    def stop(self, exit_status: str = "success", reason: str = "") -> None:
        """Close the session for good with "success", "aborted" or "failed".

        "success" is refused while an attempt is open; otherwise the open attempt is abandoned.
        """
        self._require_writable()
        if exit_status not in _EXIT_STATUSES:
            raise SessionError(f"exit_status must be one of {_EXIT_STATUSES}, got {exit_status!r}")
        if exit_status == "success" and self._state.open is not None:
            raise SessionError(
                f"step {self._state.open.step!r} attempt {self._state.open.attempt} is still open; "
                "end_step it first, or stop with exit_status 'aborted' or 'failed'"
            )
        self._abandon_open(f"session stopped: {exit_status}")
        self._append(SessionStop(**self._stamp(), exit_status=exit_status, reason=reason))
        self._write_manifest(self._state.status)
        self.close()

    def close(self) -> None:
        """Release the session without stopping it: it stays interrupted and can be resumed."""
        self._journal.close()

    # -- internals ------------------------------------------------------------------------------

    def _stamp(self) -> dict[str, Any]:
        return {"seq": self._state.next_seq, "time_utc": _utc_now()}

    def _append(self, record: Record) -> None:
        """Journal a record the state accepts; a failed append closes the writer."""
        journal = self._require_writable()
        self._state.check(record)
        try:
            journal.append(record)
        except OSError as exc:
            self.close()
            raise SessionError(
                f"cannot append to {journal.path} ({exc}); the writer is closed and everything "
                "journaled before is safe: fix the cause (disk full? read-only?), then resume "
                "the session"
            ) from exc
        self._state.apply(record)

    def _require_writable(self) -> JournalWriter:
        if self._journal.superseded:
            raise SessionError(
                f"this writer of {self._path} was superseded by a newer SessionWriter of the same "
                "session in this process (SessionWriter.resume); use that one"
            )
        if self._journal.closed:
            raise SessionError(
                f"the writer of {self._path} is closed; SessionWriter.resume it if it was not "
                "stopped, else start a new session"
            )
        return self._journal

    def _open_attempt(self, step: str) -> int:
        """The attempt number of the open attempt at `step`, or a SessionError saying why not."""
        self._require_writable()
        opened = self._state.open
        if opened is not None and opened.step == step:
            return opened.attempt
        if step in self._state.completed:
            raise SessionError(f"step {step!r} is already completed; it cannot change any more")
        now = f"; step {opened.step!r} is open" if opened else ""
        raise SessionError(
            f"step {step!r} has no open attempt{now}; call begin_step({step!r}) first"
        )

    def _abandon_open(self, reason: str) -> None:
        opened = self._state.open
        if opened is not None:
            self._append(
                StepAbandoned(
                    **self._stamp(), step=opened.step, attempt=opened.attempt, reason=reason
                )
            )

    def _write_file(
        self,
        step: str,
        name: str,
        fill: Callable[[BinaryIO], object],
        role: FileRole,
        meta: dict[str, Any],
    ) -> Path:
        """Write a file of the open attempt atomically, then journal it; return its path."""
        attempt = self._open_attempt(step)
        assert self._state.open is not None
        relative = f"{self._state.open.dir}/{name}"
        if name in self._state.open.files:
            raise SessionError(
                f"{relative} was already written in this attempt; choose another name"
            )
        target = self._path / relative
        try:
            digest = write_atomic(target, fill)
        except SessionError:
            raise
        except (OSError, RuntimeError) as exc:  # RuntimeError: libsndfile's errors
            raise SessionError(
                f"cannot write {target} ({exc}); nothing was journaled for it and every "
                "completed step is safe: fix the cause (disk full? read-only?), then capture "
                f"step {step} again"
            ) from exc
        self._append(
            FileWritten(
                **self._stamp(),
                step=step,
                attempt=attempt,
                path=relative,
                sha256=digest.sha256,
                bytes=digest.bytes,
                role=role,
                meta=meta,
            )
        )
        return target

    def _write_manifest(self, status: SessionStatus) -> None:
        _write_manifest(self._path, self._state.manifest(status))


def _write_manifest(path: Path, manifest: SessionManifest) -> None:
    """Replace the session's manifest.json atomically."""
    text = manifest.model_dump_json(indent=2) + "\n"
    try:
        write_atomic(path / MANIFEST_NAME, lambda fh: fh.write(text.encode()), replace=True)
    except OSError as exc:
        raise SessionError(
            f"cannot rewrite {path / MANIFEST_NAME} ({exc}); the journal is up to date and "
            "remains the truth: fix the cause (disk full?) and resume the session"
        ) from exc
