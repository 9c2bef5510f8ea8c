"""Where a session's files go: the attempt directories (shared by the writer and the replay)."""

from __future__ import annotations

import re

_ATTEMPT_DIR_RE = re.compile(r"(?:([^/]+)s/)?([^/]+)-a([0-9]+)")


def attempt_dir(step: str, attempt: int) -> str:
    """The session-relative directory of an attempt: the step id made into a path.

    "group/name" -> "groups/name-aN" (an "s" is appended to the group), "name" -> "name-aN".
    The mapping is one-to-one, and no attempt directory can collide with a group folder (those
    end in "s", attempt directories in "-a<digits>") or with journal.jsonl / manifest.json.
    """
    group, _, name = step.rpartition("/")
    return f"{group}s/{name}-a{attempt}" if group else f"{name}-a{attempt}"


def attempt_of_dir(directory: str) -> tuple[str, int] | None:
    """The step id and attempt number whose attempt directory is `directory`, the inverse of
    `attempt_dir` ("poses/0003-a1" -> ("pose/0003", 1)); None for a path no attempt has."""
    match = _ATTEMPT_DIR_RE.fullmatch(directory)
    if match is None:
        return None
    group, name, attempt = match.groups()
    step = f"{group}/{name}" if group else name
    return (step, int(attempt)) if attempt_dir(step, int(attempt)) == directory else None
