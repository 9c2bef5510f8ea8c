"""A session's quality and calibration files for clients (`session.report`, `session.file`).

A client (the operator's page) names a session by id and a file by a safe relative path under
the session's `calibration/` directory (result.json, live.json, the live history, a report and
its figures). Nothing else of the machine can be read: the id is one safe name under the
session root, the path a safe relative path (acquisition.safe_names) under calibration/, opened
segment by segment beneath the session directory without following a symbolic link anywhere,
the file must be a regular file with one hard link (another name of it may be anywhere on the
disk), and it is read only up to MAX_FILE_BYTES.
"""

from __future__ import annotations

import base64
import json
import os
import stat
from pathlib import Path

from acquisition.contracts.session import SessionError, SessionReader
from acquisition.contracts.safe_names import is_relative_path
from acquisition.contracts.session._layout import attempt_dir
from acquisition.contracts.protocol import (
    CalibrationFile,
    PoseQuality,
    SessionFileResult,
    SessionReportResult,
    SessionSummary,
)

from .open_beneath import check_sendable, open_beneath
from .run import QUALITY_FILE

CALIBRATION_PREFIX = "calibration/"
MAX_FILE_BYTES = 4 * 2**20
"""The largest file `session.file` sends (a report figure is a few hundred kilobytes)."""
MAX_REPORT_FILES = 200
MAX_QUALITY_BYTES = 2**20


def session_dir(root: Path, session_id: str) -> Path:
    """The directory of session `session_id` (a safe name) under `root`; SessionError if
    there is none."""
    path = root / session_id
    if not path.is_dir() or path.is_symlink():
        raise SessionError(f"there is no session {session_id} in {root}")
    return path


def session_report(path: Path, summary: SessionSummary) -> SessionReportResult:
    """The quality of every completed step of the session at `path`, and its calibration
    files (SessionError if its journal cannot be read)."""
    reader = SessionReader(path)
    steps = []
    for step, record in reader.steps().items():
        quality = _quality(path, f"{attempt_dir(step, record.attempt)}/{QUALITY_FILE}")
        steps.append(PoseQuality(step=step, **quality))
    return SessionReportResult(session=summary, steps=steps, files=_calibration_files(path))


def _quality(session: Path, relative: str) -> dict:
    """What a step's quality.json (`relative` in `session`, opened as `session_file` opens
    what it sends) says of its images ({} when it says nothing readable)."""
    try:
        fd = open_beneath(session, relative)
        try:
            info = check_sendable(fd, relative, MAX_QUALITY_BYTES)
            data = json.loads(os.pread(fd, info.st_size, 0))
        finally:
            os.close(fd)
        return {"checkerboard_found": {str(k): bool(v)
                                       for k, v in data["checkerboard_found"].items()},
                "warnings": [str(w) for w in data.get("warnings", [])]}
    except (SessionError, OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def _calibration_files(session: Path) -> list[CalibrationFile]:
    """The files under calibration/ that `session_file` sends (regular, one link, no symbolic
    link on the way), sorted."""
    found: list[CalibrationFile] = []
    top = session / CALIBRATION_PREFIX.rstrip("/")
    if top.is_symlink() or not top.is_dir():
        return found
    for directory, dirs, files in os.walk(top, followlinks=False):
        dirs.sort()
        for name in sorted(files):
            full = Path(directory) / name
            info = full.lstat()
            if _sendable(info) and not name.endswith(".partial"):
                found.append(CalibrationFile(path=str(full.relative_to(session)),
                                             bytes=info.st_size))
            if len(found) >= MAX_REPORT_FILES:
                return found
    return found


def _sendable(info: os.stat_result) -> bool:
    """A regular file with one name: a hard link's other name may be anywhere on the disk."""
    return stat.S_ISREG(info.st_mode) and info.st_nlink == 1


def session_file(path: Path, relative: str) -> SessionFileResult:
    """The bytes of `relative` (under calibration/) in the session at `path`; SessionError
    says why a file cannot be sent: not a safe path under calibration/, a symbolic link
    anywhere on its way, not a regular file, more than one hard link, longer than
    MAX_FILE_BYTES (acquisition.daemon.open_beneath)."""
    if not relative.startswith(CALIBRATION_PREFIX) or not is_relative_path(relative):
        raise SessionError(f"{relative}: only files under {CALIBRATION_PREFIX} are sent")
    fd = open_beneath(path, relative)
    try:
        info = check_sendable(fd, relative, MAX_FILE_BYTES)
        data = os.pread(fd, info.st_size, 0)
    finally:
        os.close(fd)
    return SessionFileResult(path=relative, bytes=len(data),
                             content_b64=base64.b64encode(data).decode("ascii"))
