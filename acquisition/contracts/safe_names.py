"""Names and relative paths that arrive from files and messages, checked before any use.

A session id, a step id, a job id or a file name read from a journal, an outbox file or a
ZeroMQ message becomes part of a path (a session directory, an outbox file, a worker's cache)
or of a log line. Each is therefore held to one grammar: segments of letters, digits, `_`, `.`
and `-` that begin with a letter or digit. So no segment is `.` or `..` or empty, no path is
absolute, nothing holds a space, a NUL, a backslash or a control character, and a path made
of such segments under a directory stays inside it. Lengths are bounded.

This module is light (re and pydantic only): the worker imports it through the job messages.
"""

from __future__ import annotations

import re
from typing import Annotated

from pydantic import AfterValidator, Field

SEGMENT = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
NAME_RE = re.compile(SEGMENT)
STEP_RE = re.compile(rf"{SEGMENT}(/{SEGMENT})?")
RELATIVE_PATH_RE = re.compile(rf"{SEGMENT}(/{SEGMENT})*")
MAX_NAME = 200
MAX_PATH = 512


def is_name(text: object) -> bool:
    """A session id, job id or file name: one segment of at most MAX_NAME characters."""
    return isinstance(text, str) and len(text) <= MAX_NAME and NAME_RE.fullmatch(text) is not None


def is_step_id(text: object) -> bool:
    """A step id: "name" or "group/name"."""
    return isinstance(text, str) and len(text) <= MAX_NAME and STEP_RE.fullmatch(text) is not None


def is_relative_path(text: object) -> bool:
    """A path inside a directory: segments joined by "/", none of them "." or ".."."""
    return (isinstance(text, str) and len(text) <= MAX_PATH
            and RELATIVE_PATH_RE.fullmatch(text) is not None)


def _name(text: str) -> str:
    if not is_name(text):
        raise ValueError("must be letters, digits, '_', '.' and '-', beginning with a letter or "
                         f"digit, at most {MAX_NAME} characters (no '..', no '/', no spaces)")
    return text


def _relative_path(text: str) -> str:
    if not is_relative_path(text):
        raise ValueError("must be a relative path of segments made of letters, digits, '_', "
                         "'.' and '-', each beginning with a letter or digit (no '..', no "
                         f"leading '/'), at most {MAX_PATH} characters")
    return text


SafeName = Annotated[str, Field(min_length=1, max_length=MAX_NAME), AfterValidator(_name)]
"""A pydantic field holding one safe name (a session id, a job id, a file name)."""

SafeRelativePath = Annotated[str, Field(min_length=1, max_length=MAX_PATH),
                             AfterValidator(_relative_path)]
"""A pydantic field holding a relative path that stays inside its directory."""
