"""SessionReader: what calibration sees of a session, read from its journal alone.

The reader replays the journal once, when it is made (make a new reader to see later records),
and offers only completed steps: files of attempts that never reached `step_end` are invisible.
It never writes, so it can read a session while a writer is still recording into it.

Every file is checked against the journal before it is decoded: its size on disk against the
journal's record and the bound of its role (before anything is read), then its bytes are read
once and their SHA-256 compared, so a flipped bit, a truncated or missing file is a
`SessionError` naming the file, never a calibration of damaged data. A journal may have been
edited to match a hostile file, so the file's header is read next (`media_headers`): its
container, size and shape must be the ones the writer writes and the journal records, within
the decoding bounds, before a sample or pixel is decoded. What still fails to decode is a
`SessionError` too.
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

from ..media_headers import (
    MAX_IMAGE_PIXELS,
    MAX_RECORDING_VALUES,
    UnreadableMedia,
    check_recording_size,
    image_header,
    recording_header,
)
from ._atomic import sha256_file
from ._journal import load_state
from ._models import FileRecord, FileRole, SessionError, SessionManifest, SessionStatus, StepRecord

MAX_FILE_BYTES: dict[FileRole, int] = {
    "recording": 2 * MAX_RECORDING_VALUES + 2**20,
    "image": 3 * MAX_IMAGE_PIXELS + 2**20,
    "other": 64 * 2**20,
}
"""The largest file of each role read into memory, bytes: a recording or image of the
decoding bounds (16-bit codes; uncompressed BGR) plus its header, and a JSON record."""


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
            header = recording_header(data)
            if header.container not in ("WAV", "RF64") or header.subtype != "PCM_16":
                raise UnreadableMedia(f"it is {header.container} {header.subtype}, the session "
                                      "store writes 16-bit PCM WAV or RF64 only")
            check_recording_size(header.frames, header.channels)
        except UnreadableMedia as exc:
            raise self._undecodable(file, "a WAV recording", exc) from None
        shape = (header.frames, header.channels)
        expected = (file.meta.get("n_samples"), file.meta.get("n_channels"))
        if shape != expected:
            raise SessionError(
                f"{self._path / file.path}: the recording holds {shape[0]} samples of "
                f"{shape[1]} channels, the journal recorded {expected[0]} of {expected[1]}; "
                "the file or the journal was altered"
            )
        try:
            codes, rate = sf.read(io.BytesIO(data), dtype="int16", always_2d=True)
        except Exception as exc:  # libsndfile's errors, and soundfile's own on odd data
            raise self._undecodable(file, "a WAV recording", exc) from None
        if codes.shape != shape:
            raise self._undecodable(file, "a WAV recording", f"it holds {codes.shape[0]} "
                                    f"samples, its header {shape[0]}")
        return codes, rate

    def read_image(self, step: str, name: str) -> np.ndarray:
        """The image as stored: uint8 (height, width) grey or (height, width, 3) BGR."""
        file, data = self._verified(step, name, "image")
        try:
            header = image_header(data)
            if header.format != "PNG":
                raise UnreadableMedia(f"it is {header.format}, the session store writes PNG "
                                      "only")
        except UnreadableMedia as exc:
            raise self._undecodable(file, "a PNG image", exc) from None
        size = (header.height, header.width)
        expected = (file.meta.get("height"), file.meta.get("width"))
        if size != expected:
            raise SessionError(
                f"{self._path / file.path}: the image is {size[1]} x {size[0]} pixels, the "
                f"journal recorded {expected[1]} x {expected[0]}; the file or the journal was "
                "altered"
            )
        try:
            image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error as exc:
            raise self._undecodable(file, "a PNG image", exc) from None
        if image is None or image.shape[:2] != size:
            raise self._undecodable(file, "a PNG image", "OpenCV cannot decode it")
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
            size = path.stat().st_size
            if size != file.bytes or size > MAX_FILE_BYTES[role]:
                raise SessionError(
                    f"{path} (step {step!r}): size mismatch: {size} bytes, the journal "
                    f"recorded {file.bytes}" + ("" if size != file.bytes else
                                                f", more than a {role} file may hold "
                                                f"({MAX_FILE_BYTES[role]})")
                    + "; the file is damaged: restore it from a copy of the session (`micam "
                    "inspect` lists every damaged file)")
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
