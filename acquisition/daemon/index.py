"""The daemon's index of its sessions: `sessions.list` without reading journals on the loop.

Reading a session's journal costs milliseconds (benchmarks/bench_sessions_list.py) and the
daemon's one loop must answer within a burst, so a listing that reads every journal would
starve the heartbeats after a thousand sessions. The index keeps each session's summary with
the size and modification time of the journal it was read from:

- a background thread (re)reads the sessions whose journal changed: at start-up, and whenever
  a listing is asked for (at most once per `RESCAN_S`). It waits while a step is being
  captured (`busy`), so it never competes with a capture;
- the daemon re-reads a session itself, at once, when it opens or closes it (`update`), so a
  listing shows the daemon's own changes at once and changes by others after the next scan;
- the summaries are saved (atomically) to `SESSION_ROOT.index.json` beside the session root
  (as the outbox is), so that after a restart only the journals that changed are read again.
  The file is the daemon's own, but it is validated like any file: a damaged one is ignored
  and the sessions are read afresh.

After its first complete scan the index also tells the daemon which sessions completed
recently (`completed_since`), so that a final calibration job the outbox's full disk lost
before a restart is queued again.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError

from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.safe_names import SafeName, is_name
from ..sequencer import plan_steps
from acquisition.contracts.session import JOURNAL_NAME, SessionError, SessionReader
from acquisition.contracts.session import partial_path, write_atomic
from acquisition.contracts.step_ids import is_pose_step
from acquisition.contracts.protocol import SessionSummary

log = logging.getLogger("micam.daemon")

INDEX_SUFFIX = ".index.json"
RESCAN_S = 1.0  # a listing triggers a background scan at most this often
BUSY_WAIT_S = 0.05


def summarize(session_id: str, path: Path, status: str, completed: dict[str, Any],
              capture: dict, created_utc: datetime) -> SessionSummary:
    """A session's summary for `status` and `sessions.list`."""
    return SessionSummary(
        id=session_id, path=str(path), status=status, steps_done=len(completed),
        steps_total=len(plan_steps(CaptureConfig.of_session(capture, path))),
        poses_done=sum(is_pose_step(s) for s in completed),
        n_poses=capture["n_poses"], created_utc=created_utc)


class _Entry(BaseModel):
    """One session as indexed: its summary, or why it cannot be read, and the journal's
    size and modification time when it was read."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    size: int
    mtime_ns: int
    summary: SessionSummary | None = None
    problem: str | None = None


class _IndexFile(BaseModel):
    model_config = ConfigDict(extra="forbid")

    version: int = 1
    entries: dict[SafeName, _Entry]


@dataclass(frozen=True)
class Listing:
    """What `sessions.list` answers: summaries by directory name, problems, and whether
    every session of the root has been read at least once."""

    sessions: list[dict[str, Any]]
    problems: list[str]
    complete: bool


class SessionIndex:
    """Summaries of the sessions under `root` (see the module docstring)."""

    def __init__(self, root: Path, busy: Callable[[], bool] = lambda: False) -> None:
        self.root = root
        self.file = root.with_name(root.name + INDEX_SUFFIX)
        self._busy = busy
        self._entries: dict[str, _Entry] = {}
        self._json: dict[str, dict[str, Any]] = {}  # the summaries, ready for a reply
        self._interrupted: set[str] = set()
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._scanned = threading.Event()  # the first complete scan is done
        self._dirty = False
        self._last_request = 0.0
        self._thread: threading.Thread | None = None
        self._load()

    # -- the loop thread's side -------------------------------------------------------------

    def start(self) -> None:
        """Start the background thread; it scans the root at once."""
        self._thread = threading.Thread(target=self._run, name="session-index", daemon=True)
        self._thread.start()
        self._wake.set()

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(10.0)

    @property
    def complete(self) -> bool:
        return self._scanned.is_set()

    def wait_complete(self, timeout_s: float) -> bool:
        """Wait for the first complete scan (tests, benchmarks); True when it is done."""
        return self._scanned.wait(timeout_s)

    def listing(self) -> Listing:
        """Every indexed session in name order; asks for a background scan (at most once per
        RESCAN_S) so that sessions changed by others appear in a later listing."""
        now = time.monotonic()
        if now - self._last_request >= RESCAN_S:
            self._last_request = now
            self._wake.set()
        with self._lock:
            names = sorted(self._entries)
            sessions = [self._json[n] for n in names if n in self._json]
            problems = [f"{n}: {self._entries[n].problem}" for n in names
                        if self._entries[n].problem is not None]
        return Listing(sessions, problems, self.complete)

    def update(self, path: Path) -> None:
        """Read one session again now (the daemon opened or closed it)."""
        if path.parent != self.root or not is_name(path.name):
            return
        stamp = _stamp(path)
        if stamp is None:
            return
        self._store(path.name, _read(path, stamp))
        self._wake.set()  # the background thread saves the index

    def newest_interrupted(self) -> str | None:
        """The newest (by name) session that reads as interrupted, if any."""
        with self._lock:
            return max(self._interrupted, default=None)

    def completed_since(self, since_ns: int) -> list[Path]:
        """Complete sessions whose journal changed after `since_ns` (epoch nanoseconds)."""
        with self._lock:
            return [self.root / n for n, e in sorted(self._entries.items())
                    if e.summary is not None and e.summary.status == "complete"
                    and e.mtime_ns >= since_ns]

    # -- the background thread ----------------------------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait()
            self._wake.clear()
            if self._stop.is_set():
                return
            try:
                self._scan()
            except Exception:  # a bug: log it; the next request scans again
                log.exception("the session index scan failed")

    def _scan(self) -> None:
        try:
            names = [e.name for e in os.scandir(self.root)
                     if is_name(e.name) and e.is_dir(follow_symlinks=False)]
        except OSError as exc:
            log.error("cannot list the session root %s: %s", self.root, exc)
            return
        seen = set()
        for name in names:
            if not self._wait_until_idle():
                return
            path = self.root / name
            stamp = _stamp(path)
            if stamp is None:
                continue
            seen.add(name)
            with self._lock:
                entry = self._entries.get(name)
            if entry is None or (entry.size, entry.mtime_ns) != stamp:
                self._store(name, _read(path, stamp))
        with self._lock:
            gone = set(self._entries) - seen
            for name in gone:
                del self._entries[name]
                self._json.pop(name, None)
                self._interrupted.discard(name)
            self._dirty |= bool(gone)
            dirty, self._dirty = self._dirty, False
        self._scanned.set()
        if dirty:
            self._save()

    def _wait_until_idle(self) -> bool:
        """Wait while a step is captured; False once the index is closed."""
        while self._busy():
            if self._stop.wait(BUSY_WAIT_S):
                return False
        return not self._stop.is_set()

    def _store(self, name: str, entry: _Entry) -> None:
        ready = entry.summary.model_dump(mode="json") if entry.summary is not None else None
        with self._lock:
            self._entries[name] = entry
            if ready is None:
                self._json.pop(name, None)
            else:
                self._json[name] = ready
            if entry.summary is not None and entry.summary.status == "interrupted":
                self._interrupted.add(name)
            else:
                self._interrupted.discard(name)
            self._dirty = True

    # -- the index file -----------------------------------------------------------------------

    def _load(self) -> None:
        path = self.file
        try:
            data = _IndexFile.model_validate_json(path.read_bytes())
        except FileNotFoundError:
            return
        except (OSError, ValidationError) as exc:
            log.warning("ignoring the session index %s (%s); reading every session afresh",
                        path, str(exc).splitlines()[0])
            return
        for name, entry in data.entries.items():
            if entry.summary is None or entry.summary.path == str(self.root / name):
                self._store(name, entry)
        self._dirty = False

    def _save(self) -> None:
        with self._lock:
            entries = dict(self._entries)  # frozen entries: serialised outside the lock
        text = _IndexFile(entries=entries).model_dump_json().encode()
        path = self.file
        try:
            partial_path(path).unlink(missing_ok=True)
            write_atomic(path, lambda fh: fh.write(text), replace=True)
        except OSError as exc:  # a full disk: the index is rebuilt from the journals anyway
            log.warning("cannot save the session index %s: %s", path, exc)


def _stamp(session: Path) -> tuple[int, int] | None:
    """(size, mtime_ns) of the session's journal; None if it has none."""
    try:
        info = os.stat(session / JOURNAL_NAME)
    except OSError:
        return None
    return info.st_size, info.st_mtime_ns


def _read(path: Path, stamp: tuple[int, int]) -> _Entry:
    """Index one session (`stamp` taken before reading, so a change meanwhile is read again)."""
    try:
        reader = SessionReader(path)
        summary = summarize(reader.session_id, path, reader.status, reader.steps(),
                            reader.capture, reader.created_utc)
    except (SessionError, ValueError, KeyError, TypeError) as exc:
        return _Entry(size=stamp[0], mtime_ns=stamp[1], problem=str(exc))
    return _Entry(size=stamp[0], mtime_ns=stamp[1], summary=summary)

