"""`session.file` sends only a session's own calibration files: never through a symbolic link
(at the end of the path or anywhere on its way, the calibration directory itself included),
never a file with a second hard link (its other name may be anywhere on the disk), never a
FIFO or a device (and opening one does not block), and the report lists only what it sends."""

from __future__ import annotations

import base64
import os
from pathlib import Path

import pytest

from acquisition.contracts.session import SessionError
from acquisition.daemon.session_files import _calibration_files, session_file

SECRET = b"the secret of another account\n"


@pytest.fixture
def session(tmp_path: Path) -> Path:
    """A session directory with a calibration/ of its own files, beside a file of secrets."""
    (tmp_path / "secret.txt").write_bytes(SECRET)
    path = tmp_path / "session-1"
    (path / "calibration" / "figures").mkdir(parents=True)
    (path / "journal.jsonl").write_text('{"kind": "session"}\n')
    (path / "calibration" / "result.json").write_text('{"a": 1}')
    (path / "calibration" / "figures" / "array.png").write_bytes(b"\x89PNG")
    return path


def _sent(session: Path, relative: str) -> bytes:
    return base64.b64decode(session_file(session, relative).content_b64)


def test_the_sessions_own_files_are_sent(session: Path) -> None:
    assert _sent(session, "calibration/result.json") == b'{"a": 1}'
    assert _sent(session, "calibration/figures/array.png") == b"\x89PNG"
    assert [f.path for f in _calibration_files(session)] == [
        "calibration/result.json", "calibration/figures/array.png"]


def _links(session: Path) -> dict[str, str]:
    """Every way a session's calibration/ could lead elsewhere, as the path asked for and why
    it is refused."""
    calibration = session / "calibration"
    os.symlink(session.parent / "secret.txt", calibration / "stolen.json")
    os.symlink("../journal.jsonl", calibration / "journal.json")
    os.symlink(session.parent, calibration / "up")
    os.symlink(session, calibration / "inside")
    os.link(session.parent / "secret.txt", calibration / "linked.txt")
    os.link(session / "journal.jsonl", calibration / "journal.txt")
    os.mkfifo(calibration / "fifo.json")
    (calibration / "dir.json").mkdir()
    return {"calibration/stolen.json": "symbolic link",
            "calibration/journal.json": "symbolic link",
            "calibration/up/secret.txt": "symbolic link",
            "calibration/inside/journal.jsonl": "symbolic link",
            "calibration/linked.txt": "2 hard links",
            "calibration/journal.txt": "2 hard links",
            "calibration/fifo.json": "not a regular file",
            "calibration/dir.json": "not a regular file",
            "calibration/result.json/x": "result.json is not a directory",
            "calibration/../secret.txt": "only files under",
            "journal.jsonl": "only files under"}


@pytest.mark.timeout(20)  # a FIFO opened without O_NONBLOCK would hang here
def test_no_link_leads_out_of_the_calibration_directory(session: Path) -> None:
    for relative, why in _links(session).items():
        with pytest.raises(SessionError, match=why):
            session_file(session, relative)
    assert [f.path for f in _calibration_files(session)] == [
        "calibration/result.json", "calibration/figures/array.png"]


def test_a_calibration_directory_that_is_a_link_is_refused(session: Path) -> None:
    elsewhere = session.parent / "elsewhere"
    (session / "calibration").rename(elsewhere)
    os.symlink(elsewhere, session / "calibration")
    with pytest.raises(SessionError, match="symbolic link"):
        session_file(session, "calibration/result.json")
    assert _calibration_files(session) == []
