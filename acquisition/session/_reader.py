"""SessionReader: what calibration sees of a session, read from its journal alone.

The reader replays the journal once, when it is made (make a new reader to see later records),
and offers only completed steps: files of attempts that never reached `step_end` are invisible.
It never writes, so it can read a session while a writer is still recording into it.
"""

from __future__ import annotations

import copy
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
        path = self._file(step, name, "recording")
        try:
            codes, rate = sf.read(path, dtype="int16", always_2d=True)
        except (sf.LibsndfileError, RuntimeError) as exc:
            raise SessionError(f"{path}: cannot read the recording ({exc}); run verify()") from exc
        return codes, rate

    def read_image(self, step: str, name: str) -> np.ndarray:
        """The image as stored: uint8 (height, width) grey or (height, width, 3) BGR."""
        path = self._file(step, name, "image")
        image = cv2.imdecode(np.fromfile(path, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise SessionError(f"{path}: not a readable PNG image; run verify()")
        return image

    def read_json(self, step: str, name: str) -> dict[str, Any]:
        """A per-step JSON record as a dict."""
        path = self._file(step, name, "other")
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise SessionError(f"{path}: not valid JSON ({exc}); run verify()") from exc

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
        if digest.sha256 != file.sha256:
            return (
                f"checksum mismatch: {digest.bytes} bytes with sha256 {digest.sha256}, the journal "
                f"recorded {file.bytes} bytes with sha256 {file.sha256}"
            )
        return None

    def _file(self, step: str, name: str, role: FileRole) -> Path:
        """The path of a journaled file of a completed step, checking that it holds `role`."""
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
        path = self._path / file.path
        if not path.is_file():
            raise SessionError(f"{path} is missing although the journal records it; run verify()")
        return path
