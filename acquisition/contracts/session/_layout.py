"""Where a session's files go: the attempt directories (shared by the writer and the replay)."""

from __future__ import annotations


def attempt_dir(step: str, attempt: int) -> str:
    """The session-relative directory of an attempt: the step id made into a path.

    "group/name" -> "groups/name-aN" (an "s" is appended to the group), "name" -> "name-aN".
    The mapping is one-to-one, and no attempt directory can collide with a group folder (those
    end in "s", attempt directories in "-a<digits>") or with journal.jsonl / manifest.json.
    """
    group, _, name = step.rpartition("/")
    return f"{group}s/{name}-a{attempt}" if group else f"{name}-a{attempt}"
