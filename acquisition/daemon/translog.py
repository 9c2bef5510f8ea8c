"""The daemon's own log in each session directory: every state transition, one JSON line each.

`daemon.jsonl` sits beside the session's journal (the session store ignores other top-level
files). Each line is written with one `write` and fsync'd, like the journal, so after a crash
it tells what the daemon was doing; a torn last line is possible and readers skip it.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from acquisition.contracts.protocol import utc_now

TRANSITION_LOG = "daemon.jsonl"


class TransitionLog:
    """Appends records to `<session>/daemon.jsonl` durably."""

    def __init__(self, session_dir: Path) -> None:
        self.path = Path(session_dir) / TRANSITION_LOG
        self._fd: int | None = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def append(self, **record: Any) -> None:
        if self._fd is None:
            raise ValueError(f"{self.path} is closed")
        line = json.dumps({"time_utc": utc_now().isoformat(), **record}) + "\n"
        os.write(self._fd, line.encode())
        os.fsync(self._fd)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def read_transitions(session_dir: Path) -> list[dict[str, Any]]:
    """Every complete record of a session's daemon.jsonl (a torn last line is skipped)."""
    path = Path(session_dir) / TRANSITION_LOG
    if not path.is_file():
        return []
    records = []
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records
