"""Opening a file of a session for a client without leaving the session: the one way the
daemon opens what it serves (`session.file` to the page, `fetch` to the workers).

Anyone who can write a session directory can put a symbolic link, a hard link or a FIFO in
it. `open_beneath` opens a relative path one segment at a time, each relative to its
parent's descriptor with O_NOFOLLOW, so no symbolic link is followed anywhere on the way
(a realpath check before an open would race with a rename), and O_NONBLOCK, so a FIFO opens
at once instead of blocking the daemon; `check_sendable` then accepts a regular file with
exactly one name only (a hard link's other name may be anywhere on the disk).
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from acquisition.contracts.session import SessionError


def open_beneath(session: Path, relative: str) -> int:
    """A read-only descriptor of `relative` ("a/b/c") in the directory `session`, never
    through a symbolic link; SessionError says why it cannot be opened. The caller closes
    it (and judges it with `check_sendable`)."""
    segments = relative.split("/")
    try:
        directory = os.open(session, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    except OSError as exc:
        raise SessionError(f"cannot open the session directory {session}: {exc.strerror}"
                           ) from None
    try:
        for segment in segments[:-1]:
            inner = _open_at(directory, segment, relative, os.O_DIRECTORY)
            os.close(directory)
            directory = inner
        return _open_at(directory, segments[-1], relative, os.O_NONBLOCK | os.O_NOCTTY)
    finally:
        os.close(directory)


def check_sendable(fd: int, relative: str, max_bytes: int | None = None) -> os.stat_result:
    """The open file's status if it may be sent: a regular file, one hard link, at most
    `max_bytes` long (None: any length); SessionError otherwise."""
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode):
        raise SessionError(f"{relative} is not a regular file")
    if info.st_nlink != 1:
        raise SessionError(f"{relative} has {info.st_nlink} hard links; only a file with one "
                           "name is sent (another name may be anywhere on the disk)")
    if max_bytes is not None and info.st_size > max_bytes:
        raise SessionError(f"{relative} has {info.st_size} bytes; at most {max_bytes} are sent")
    return info


def _open_at(directory: int, segment: str, relative: str, flags: int) -> int:
    """`segment` of the open `directory`, read-only, never through a symbolic link."""
    try:
        return os.open(segment, os.O_RDONLY | os.O_NOFOLLOW | flags, dir_fd=directory)
    except OSError as exc:
        raise SessionError(f"{relative}: cannot open it: {_why_not(directory, segment, exc)}"
                           ) from None


def _why_not(directory: int, segment: str, exc: OSError) -> str:
    """Why `segment` of `directory` could not be opened, for a person."""
    try:
        info = os.lstat(segment, dir_fd=directory)
    except OSError:
        return str(exc.strerror)
    if stat.S_ISLNK(info.st_mode):
        return f"{segment} is a symbolic link (none is followed)"
    return f"{segment} is not a directory" if exc.errno == errno.ENOTDIR else str(exc.strerror)
