"""The worker's copy of sessions: every fetched file verified against the journal's SHA-256.

A session's files never change once journaled, so a file present under its final name in the
cache is the verified one and is never fetched again: a live job after each pose fetches only
that pose, and the final job only the journal. Files arrive as `<name>.partial`, are hashed,
and are renamed only if the digest matches. One cache directory serves one worker at a time.

The cache is bounded: beyond `max_bytes` (the files' sizes on disk, summed) whole sessions are
evicted, least recently used first. A session's last use is its directory's modification time,
set when a job takes it and when the job ends, so the order survives a restart of the worker.
A session a job is using (`FileCache.use`) is never evicted; if it alone is larger than the
limit it stays until its job ends, and is evicted after (each job then fetches it afresh).
Only session mirrors (directories holding the journal) are counted and evicted.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from acquisition.contracts.job_messages import Job, JobFile
from acquisition.contracts.safe_names import is_name
from acquisition.contracts.session import sha256_file

from ..errors import CalibrationInputError

JOURNAL = "journal.jsonl"
DEFAULT_MAX_BYTES = 4 * 2**30
"""The cache's default size limit, bytes. 4 GiB: at roughly 20 MB per pose (72 microphones,
int16, order-14 bursts, 6 speakers, 3 images; an estimate) about ten 20-pose sessions."""

log = logging.getLogger("micam.worker")


class ChecksumMismatch(Exception):
    """A fetched file's bytes are not those the journal recorded."""


@dataclass(frozen=True)
class CachedSession:
    """One session's mirror in the cache: its size on disk (bytes, every file, `.partial`
    ones included) and its last use (the directory's mtime, nanoseconds since the epoch)."""

    session_id: str
    path: Path
    bytes: int
    last_used_ns: int


class FileCache:
    """Session mirrors under `root` (one directory per session id), at most `max_bytes` bytes
    of them unless the sessions in use alone are larger (see the module docstring)."""

    def __init__(self, root: Path, max_bytes: int = DEFAULT_MAX_BYTES) -> None:
        if max_bytes <= 0:
            raise ValueError(f"the cache's size limit must be positive; got {max_bytes} bytes")
        self.root = Path(root).expanduser()
        self.root.mkdir(parents=True, exist_ok=True)
        self.max_bytes = max_bytes
        self._in_use: Counter[str] = Counter()
        self._lock = threading.Lock()

    @contextmanager
    def use(self, job: Job) -> Iterator[Path]:
        """Hold the job's session for the `with` block (fetch and calibration): it is marked
        most recently used and is not evicted until the block ends. Other sessions are evicted
        first to make room for the files it still lacks, and again when the block ends."""
        session = self.session_dir(job)
        with self._lock:
            self._in_use[job.session_id] += 1
        try:
            session.mkdir(parents=True, exist_ok=True)
            _touch(session)
            self.evict(reserve=sum(f.bytes for f in self.wanted(job)))
            yield session
        finally:
            with self._lock:
                self._in_use[job.session_id] -= 1
                if self._in_use[job.session_id] <= 0:
                    del self._in_use[job.session_id]
            if session.is_dir():
                _touch(session)  # its last use is when its job ended
            self.evict()

    def in_use(self) -> set[str]:
        """The ids of the sessions a job is using now."""
        with self._lock:
            return set(self._in_use)

    def sessions(self) -> list[CachedSession]:
        """The cached sessions, least recently used first; sizes measured on disk now."""
        found = []
        for entry in self.root.iterdir():
            try:
                if _is_mirror(entry):
                    found.append(CachedSession(entry.name, entry, _size_on_disk(entry),
                                               entry.stat().st_mtime_ns))
            except FileNotFoundError:
                continue  # removed meanwhile
        return sorted(found, key=lambda s: (s.last_used_ns, s.session_id))

    def total_bytes(self) -> int:
        """The size of every cached file, bytes."""
        return sum(s.bytes for s in self.sessions())

    def evict(self, reserve: int = 0) -> list[str]:
        """Remove whole sessions, least recently used first and never one in use, until the
        cache plus `reserve` bytes fits in `max_bytes`. Returns the evicted session ids."""
        evicted: list[str] = []
        with self._lock:
            sessions = self.sessions()
            total = sum(s.bytes for s in sessions)
            for s in sessions:
                if total + reserve <= self.max_bytes:
                    break
                if s.session_id in self._in_use:
                    continue
                try:
                    shutil.rmtree(s.path)
                except OSError as exc:
                    log.warning("cannot evict session %s from the cache: %s", s.session_id, exc)
                    continue
                log.info("evicted session %s (%d bytes) from the cache", s.session_id, s.bytes)
                total -= s.bytes
                evicted.append(s.session_id)
            if total + reserve > self.max_bytes:
                log.warning("the cache needs %d bytes for the sessions in use, more than its "
                            "limit of %d; raise --cache-max above the largest session",
                            total + reserve, self.max_bytes)
        return evicted

    def session_dir(self, job: Job) -> Path:
        """The job's session mirror; CalibrationInputError for a session id that is not a name
        (the job message refuses one already: this guards the cache on its own)."""
        if not is_name(job.session_id):
            raise CalibrationInputError(
                f"the job names the session {job.session_id!r}, which is not a "
                "plain directory name")
        return self.root / job.session_id

    def target(self, job: Job, rel: str) -> Path:
        """Where `rel` of the job's session goes; CalibrationInputError for a path leaving it."""
        parts = PurePosixPath(rel).parts
        if PurePosixPath(rel).is_absolute() or ".." in parts or not parts:
            raise CalibrationInputError(
                f"the job names the file {rel!r}, which is not inside its session")
        return self.session_dir(job).joinpath(*parts)

    def wanted(self, job: Job) -> list[JobFile]:
        """The job's files to fetch (those not cached yet), and always its journal prefix."""
        missing = [f for f in job.files if not self.target(job, f.path).is_file()]
        journal = JobFile(path=JOURNAL, bytes=job.journal.bytes, sha256=job.journal.sha256)
        return [*missing, journal]

    def partial(self, job: Job, rel: str) -> Path:
        path = self.target(job, rel)
        path.parent.mkdir(parents=True, exist_ok=True)
        return path.with_name(path.name + ".partial")

    def commit(self, job: Job, file: JobFile) -> None:
        """Verify the fetched `<name>.partial` and give it its name; ChecksumMismatch if not."""
        partial = self.partial(job, file.path)
        digest = sha256_file(partial)
        if digest.sha256 != file.sha256 or digest.bytes != file.bytes:
            partial.unlink(missing_ok=True)
            raise ChecksumMismatch(
                f"{file.path}: fetched {digest.bytes} bytes with sha256 {digest.sha256}, but the "
                f"journal recorded {file.bytes} bytes with sha256 {file.sha256}; the daemon's "
                f"copy may be damaged (check it with `micam inspect SESSION`)")
        os.replace(partial, self.target(job, file.path))


def _is_mirror(entry: Path) -> bool:
    """Whether `entry` is a session mirror this cache made: a directory with the journal (or
    its `.partial`, created as a fetch starts), or an empty one. Anything else under the root
    (a --cache pointed at a directory of other things) is neither counted nor evicted."""
    if entry.is_symlink() or not entry.is_dir():
        return False
    journal = entry / JOURNAL
    return (journal.exists() or journal.with_name(JOURNAL + ".partial").exists()
            or next(entry.iterdir(), None) is None)


def _touch(path: Path) -> None:
    now = time.time_ns()
    os.utime(path, ns=(now, now))


def _size_on_disk(directory: Path) -> int:
    """The summed sizes of the files under `directory`, bytes (symbolic links not followed)."""
    total = 0
    for parent, _dirs, files in os.walk(directory):
        for name in files:
            try:
                total += os.lstat(os.path.join(parent, name)).st_size
            except FileNotFoundError:
                continue
    return total


_UNITS = {"": 1, "B": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40,
          "KIB": 2**10, "MIB": 2**20, "GIB": 2**30, "TIB": 2**40,
          "KB": 10**3, "MB": 10**6, "GB": 10**9, "TB": 10**12}


def parse_size(text: str) -> int:
    """A size such as `4GiB`, `500M`, `2GB` or `1048576` in bytes (K, M, G, T and KiB … TiB
    are powers of 1024; KB … TB powers of 1000). CalibrationInputError, saying what is
    accepted, if not."""
    match = re.fullmatch(r"\s*(\d+(?:\.\d*)?)\s*([A-Za-z]*)\s*", text)
    unit = _UNITS.get(match.group(2).upper()) if match else None
    if match is None or unit is None:
        raise CalibrationInputError(
            f"{text!r} is not a size; write bytes, or a number with a unit such "
            "as 500MiB, 4GiB or 2GB")
    size = int(float(match.group(1)) * unit)
    if size <= 0:
        raise CalibrationInputError(f"{text!r}: the size must be at least one byte")
    return size
