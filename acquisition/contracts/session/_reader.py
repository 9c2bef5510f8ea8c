"""SessionReader: what calibration sees of a session, read from its journal alone.

The reader replays the journal once, when it is made (make a new reader to see later records),
and offers only completed steps: files of attempts that never reached `step_end` are invisible.
It never writes, so it can read a session while a writer is still recording into it.

Every file is checked against the journal before it is decoded: its bytes are read once,
their size and SHA-256 compared with the journal's record, and only then decoded from memory,
so a flipped bit, a truncated or missing file is a `SessionError` naming the file, never a
calibration of damaged data. What still fails to decode (a file that matches a hand-edited
journal) is a `SessionError` too, as is a recording or image whose shape is not the one the
journal recorded.
"""

from __future__ import annotations

import copy
import hashlib
import io
import json
from datetime import datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import soundfile as sf

from ._atomic import sha256_file
from ._journal import load_state
from ._models import FileRecord, FileRole, SessionError, SessionManifest, SessionStatus, StepRecord


class SessionReader:
    """Read-only access to a session directory (complete, stopped early, or interrupted)."""

    def __init__(self, path: Path) -> None:
        self._path = Path(path)
        if not self._path.is_dir():
            raise SessionError(f"{self._path} is not a directory; pass a session directory")
        self._state, _ = load_state(self._path)

    @property
    def path(self) -> Path:
        return self._path

    @property
    def session_id(self) -> str:
        return self._state.start.session_id

    @property
    def created_utc(self) -> datetime:
        return self._state.start.time_utc

    @property
    def capture(self) -> dict:
        """A copy of the capture configuration the session was recorded with."""
        return copy.deepcopy(self._state.start.capture)

    @property
    def status(self) -> SessionStatus:
        """ "complete" (stopped with success), "aborted", "failed", or "interrupted" (no stop).

        A session still being written also reads as "interrupted".
        """
        return self._state.status

    def steps(self) -> dict[str, StepRecord]:
        """The completed steps, each with the attempt that completed it and its files by name."""
        return dict(self._state.completed)

    def manifest(self) -> SessionManifest:
        """The manifest rebuilt from the journal, with the status this reader reports."""
        return self._state.manifest(self.status)

    def read_recording(self, step: str, name: str) -> tuple[np.ndarray, int]:
        """The raw int16 codes, shape (n_samples, n_channels), and the sample rate in hertz."""
        file, data = self._verified(step, name, "recording")
        try:
            codes, rate = sf.read(io.BytesIO(data), dtype="int16", always_2d=True)
        except Exception as exc:  # libsndfile's errors, and soundfile's own on odd headers
            raise self._undecodable(file, "a WAV recording", exc) from None
        expected = (file.meta.get("n_samples"), file.meta.get("n_channels"))
        if None not in expected and codes.shape != expected:
            raise SessionError(
                f"{self._path / file.path}: the recording holds {codes.shape[0]} samples of "
                f"{codes.shape[1]} channels, the journal recorded {expected[0]} of {expected[1]}; "
                "the file or the journal was altered"
            )
        return codes, rate

    def read_image(self, step: str, name: str) -> np.ndarray:
        """The image as stored: uint8 (height, width) grey or (height, width, 3) BGR."""
        file, data = self._verified(step, name, "image")
        try:
            image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:
            raise self._undecodable(file, "a PNG image", exc) from None
        if image is None:
            raise self._undecodable(file, "a PNG image", "OpenCV cannot decode it")
        expected = (file.meta.get("height"), file.meta.get("width"))
        if None not in expected and image.shape[:2] != expected:
            raise SessionError(
                f"{self._path / file.path}: the image is {image.shape[1]} x {image.shape[0]} "
                f"pixels, the journal recorded {expected[1]} x {expected[0]}; the file or the "
                "journal was altered"
            )
        return image

    def read_json(self, step: str, name: str) -> dict[str, Any]:
        """A per-step JSON record as a dict."""
        file, data = self._verified(step, name, "other")
        try:
            value = json.loads(data.decode("utf-8"))
        except (ValueError, RecursionError) as exc:  # not UTF-8, not JSON, absurd numbers
            raise self._undecodable(file, "JSON", exc) from None
        if not isinstance(value, dict):
            raise self._undecodable(file, "a JSON object", f"it is a {type(value).__name__}")
        return value

    def verify(self) -> list[str]:
        """Re-hash every file of every completed step; one line per problem, empty when intact."""
        problems = []
        for record in self._state.completed.values():
            for file in record.files.values():
                problem = self._check_file(file)
                if problem:
                    problems.append(f"{file.path} (step {record.step!r}): {problem}")
        return problems

    def _check_file(self, file: FileRecord) -> str | None:
        path = self._path / file.path
        if not path.is_file():
            return "missing"
        digest = sha256_file(path)
        return _mismatch(file, digest.bytes, digest.sha256)

    def _verified(self, step: str, name: str, role: FileRole) -> tuple[FileRecord, bytes]:
        """The journal's record of a file and its bytes, once they match the record."""
        file = self._file(step, name, role)
        path = self._path / file.path
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            raise SessionError(
                f"{path} (step {step!r}): missing, although the journal records it; restore it "
                "from a copy of the session (`micam inspect` lists every damaged file)"
            ) from None
        except OSError as exc:
            raise SessionError(f"{path} (step {step!r}) cannot be read: {exc}") from None
        problem = _mismatch(file, len(data), hashlib.sha256(data).hexdigest())
        if problem:
            raise SessionError(f"{path} (step {step!r}): {problem}; the file is damaged: restore "
                               "it from a copy of the session (`micam inspect` lists every "
                               "damaged file)")
        return file, data

    def _undecodable(self, file: FileRecord, what: str, why: object) -> SessionError:
        why = " ".join(str(why).split())  # one line (OpenCV's messages end in a newline)
        return SessionError(
            f"{self._path / file.path}: not readable as {what} ({why}), although it matches the "
            "journal's checksum: the journal was altered, or the file was written by another "
            "program"
        )

    def _file(self, step: str, name: str, role: FileRole) -> FileRecord:
        """The journal's record of a file of a completed step, checking that it holds `role`."""
        record = self._state.completed.get(step)
        if record is None:
            raise SessionError(
                f"{self._path} has no completed step {step!r}; completed steps: "
                f"{sorted(self._state.completed) or 'none'}"
            )
        file = record.files.get(name)
        if file is None:
            raise SessionError(
                f"step {step!r} of {self._path} has no file {name!r}; it has {sorted(record.files)}"
            )
        if file.role != role:
            raise SessionError(f"{file.path} holds role {file.role!r}, not {role!r}")
        return file


def _mismatch(file: FileRecord, n_bytes: int, sha256: str) -> str | None:
    """What is wrong with a file of `n_bytes` bytes and digest `sha256` that the journal
    recorded as `file`, or None when it is the recorded one."""
    if n_bytes == file.bytes and sha256 == file.sha256:
        return None
    return (f"checksum mismatch: {n_bytes} bytes with sha256 {sha256}, the journal recorded "
            f"{file.bytes} bytes with sha256 {file.sha256}")
