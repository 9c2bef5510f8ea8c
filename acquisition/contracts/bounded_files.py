"""A user's file (a configuration, an option's file, an import description), read once with
its size bounded while it is read: the one way micam reads such files.

- **Once, through one open file.** A file may come through a pipe (`--config <(...)`,
  /dev/stdin), which can be read only once: whatever checks such a file and whatever loads it
  share one reading (`read_at_most`, then parse the bytes), or the second would see nothing
  and a daemon would run on its defaults after a check that passed.
- **Bounded before and while reading.** A regular file larger than the limit is refused by
  its size; a pipe's size is unknown until its end, so at most `limit + 1` bytes are read and
  more than `limit` is refused (/dev/zero included).
- **Never waiting on nothing.** The file is opened without blocking: a FIFO that nothing
  writes to reads as its end at once and is refused, where a plain open would wait forever;
  a directory is refused.

Files inside a session, which anyone who can write the session may have planted, are read
by the session store and the daemon's own checks instead (acquisition.daemon.open_beneath).
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
import tomllib
from pathlib import Path
from typing import Any

from .errors import UserError

MAX_TOML_BYTES = 2**20
"""The largest configuration read (1 MiB): a configuration is a few kilobytes."""
MAX_DOCUMENT_BYTES = 64 * 2**20
"""Largest result.json, truth.json or geometry XML a command reads (a result of 1024
microphones with their responses is a few megabytes)."""


class UnreadableFile(UserError):
    """A file is missing, a directory, a FIFO nothing writes to, larger than its kind may be,
    or not UTF-8 text; the message names the file and the problem."""


class TooLarge(UnreadableFile):
    """The file holds more than its limit (the message names the file and the limit)."""


def read_at_most(path: Path, limit: int) -> bytes:
    """The bytes of `path`, read once through one open file, at most `limit` of them.

    Raises:
        TooLarge: it holds more than `limit` bytes.
        UnreadableFile: it cannot be opened or read, is a directory, or is a FIFO that
            nothing writes to.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except OSError as exc:
        raise UnreadableFile(f"{path} cannot be read: {exc.strerror}") from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise UnreadableFile(f"{path} is a directory, not a file")
        if stat.S_ISREG(info.st_mode) and info.st_size > limit:
            raise TooLarge(f"{path} is larger than {size_text(limit)}")
        first = _first_bytes(fd, path, limit + 1) if stat.S_ISFIFO(info.st_mode) else b""
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
        with os.fdopen(os.dup(fd), "rb") as fh:
            data = first + fh.read(limit + 1 - len(first))
    except OSError as exc:
        raise UnreadableFile(f"{path} cannot be read: {exc.strerror}") from None
    finally:
        os.close(fd)
    if len(data) > limit:
        raise TooLarge(f"{path} is larger than {size_text(limit)}")
    return data


def _first_bytes(fd: int, path: Path, most: int) -> bytes:
    """What a FIFO holds now without waiting (b"" if its writer has written nothing yet);
    UnreadableFile if nothing writes to it (its end at once, before any byte)."""
    try:
        data = os.read(fd, most)
    except BlockingIOError:
        return b""  # a writer that has not written yet (a process substitution): wait for it
    except OSError as exc:
        if exc.errno == errno.EAGAIN:
            return b""
        raise
    if not data:
        raise UnreadableFile(f"{path} is not a regular file, and nothing writes to it")
    return data


def read_bounded_text(path: Path, max_bytes: int) -> str:
    """The UTF-8 text of `path` (`read_at_most`), of at most `max_bytes` bytes.

    Raises:
        UnreadableFile: as `read_at_most`, or not UTF-8.
    """
    data = read_at_most(path, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UnreadableFile(f"{path} is not UTF-8 text ({exc.reason} at byte "
                             f"{exc.start})") from None


def read_toml(path: Path, what: str, error: type[UserError],
              limit: int = MAX_TOML_BYTES) -> dict[str, Any]:
    """The TOML document in `path`, read once by `read_at_most`. `what` names the file in the
    messages ("config file"); every problem (missing, unreadable, too large, not UTF-8, not
    TOML) raises `error`, the caller's input-error class, with one line saying what is wrong."""
    if not os.path.lexists(path):
        raise error(f"{what} {path} does not exist")
    try:
        text = read_bounded_text(path, limit)
    except TooLarge:
        raise error(f"{what} {path} is larger than {size_text(limit)}; a configuration is a few "
                    "kilobytes: is it the right file?") from None
    except UnreadableFile as exc:
        raise error(f"{what}: {exc}") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {path} is not valid TOML: {exc}") from None


def size_text(size: float) -> str:
    """`size` bytes for a person: "1 MiB", "64 KiB", "1024 TiB", "100 bytes"."""
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if size >= scale and size % scale == 0:
            return f"{int(size // scale)} {unit}"
    return f"{size:g} bytes"
