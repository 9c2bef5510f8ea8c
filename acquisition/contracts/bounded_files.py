"""Small text files named on the command line or in a description, read with their size
bounded before anything is read.

An intrinsics file, a prior geometry, a truth file or an import description is a few kilobytes
to a few megabytes; a path to a multi-gigabyte file, a FIFO or a device must be refused in
words, never read into memory or waited on.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from .errors import UserError

MAX_DOCUMENT_BYTES = 64 * 2**20
"""Largest result.json, truth.json or geometry XML a command reads (a result of 1024
microphones with their responses is a few megabytes)."""


class UnreadableFile(UserError):
    """A file is missing, not a regular file, larger than its kind may be, or not UTF-8 text;
    the message names the file and the problem."""


def read_bounded_text(path: Path, max_bytes: int) -> str:
    """The UTF-8 text of the regular file `path`, of at most `max_bytes` bytes.

    Raises:
        UnreadableFile: missing, unreadable, not a regular file, too large or not UTF-8.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO must not block the open
    except OSError as exc:
        raise UnreadableFile(f"{path} cannot be read: {exc.strerror}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise UnreadableFile(f"{path} is not a regular file")
        if info.st_size > max_bytes:
            raise UnreadableFile(f"{path} is {info.st_size} bytes, more than the {max_bytes} "
                                 "a file of its kind may hold")
        with os.fdopen(os.dup(fd), "rb") as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise UnreadableFile(f"{path} cannot be read: {exc.strerror}") from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:  # it grew since fstat
        raise UnreadableFile(f"{path} is more than the {max_bytes} bytes a file of its kind "
                             "may hold")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UnreadableFile(f"{path} is not UTF-8 text ({exc.reason} at byte "
                             f"{exc.start})") from None
