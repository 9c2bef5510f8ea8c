"""A user's file read once, its size bounded while it is read.

A file may come through a pipe (`--config <(...)`, a FIFO, /dev/stdin), which can be read only
once: whatever checks such a file and whatever loads it must share one reading, or the second
sees nothing (and a daemon would run on its defaults after a check that passed). Its size is
unknown before its end (a pipe's `stat` says 0), so the limit is enforced while reading: at
most `limit + 1` bytes are read, and a file of more than `limit` is refused.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

from .errors import UserError

MAX_TOML_BYTES = 2**20
"""The largest TOML file read (1 MiB): a configuration is a few kilobytes."""


class TooLarge(UserError):
    """The file holds more than the limit (its message names the file and the limit)."""


def read_at_most(path: Path, limit: int) -> bytes:
    """The bytes of `path`, read once through one open file. Raises OSError as opening and
    reading do, and TooLarge if it holds more than `limit` bytes."""
    with open(path, "rb") as fh:
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise TooLarge(f"{path} is larger than {size_text(limit)}")
    return data


def read_toml(path: Path, what: str, error: type[UserError],
              limit: int = MAX_TOML_BYTES) -> dict[str, Any]:
    """The TOML document in `path`, read once by `read_at_most`. `what` names the file in the
    messages ("config file"); every problem (missing, unreadable, too large, not UTF-8, not
    TOML) raises `error`, the caller's input-error class, with one line saying what is wrong."""
    try:
        data = read_at_most(path, limit)
    except FileNotFoundError:
        raise error(f"{what} {path} does not exist") from None
    except TooLarge:
        raise error(f"{what} {path} is larger than {size_text(limit)}; a configuration is a few "
                    "kilobytes: is it the right file?") from None
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc}") from None
    try:
        return tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path} is not UTF-8 text: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{what} {path} is not valid TOML: {exc}") from None


def size_text(size: float) -> str:
    """`size` bytes for a person: "1 MiB", "64 KiB", "1024 TiB", "100 bytes"."""
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if size >= scale and size % scale == 0:
            return f"{int(size // scale)} {unit}"
    return f"{size:g} bytes"
