"""The worker's copy of sessions: every fetched file verified against the journal's SHA-256.

A session's files never change once journaled, so a file present under its final name in the
cache is the verified one and is never fetched again: a live job after each pose fetches only
that pose, and the final job only the journal. Files arrive as `<name>.partial`, are hashed,
and are renamed only if the digest matches. One cache directory serves one worker at a time.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path, PurePosixPath

from acquisition.daemon.job_messages import Job, JobFile

JOURNAL = "journal.jsonl"


class ChecksumMismatch(Exception):
    """A fetched file's bytes are not those the journal recorded."""


class FileCache:
    """Session mirrors under `root` (one directory per session id)."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root).expanduser()
        self.root.mkdir(parents=True, exist_ok=True)

    def session_dir(self, job: Job) -> Path:
        return self.root / job.session_id

    def target(self, job: Job, rel: str) -> Path:
        """Where `rel` of the job's session goes; ValueError for a path leaving the session."""
        parts = PurePosixPath(rel).parts
        if PurePosixPath(rel).is_absolute() or ".." in parts or not parts:
            raise ValueError(f"the job names the file {rel!r}, which is not inside its session")
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
        digest = hashlib.sha256()
        size = 0
        with partial.open("rb") as fh:
            while block := fh.read(1 << 20):
                digest.update(block)
                size += len(block)
        if digest.hexdigest() != file.sha256 or size != file.bytes:
            partial.unlink(missing_ok=True)
            raise ChecksumMismatch(
                f"{file.path}: fetched {size} bytes with sha256 {digest.hexdigest()}, but the "
                f"journal recorded {file.bytes} bytes with sha256 {file.sha256}; the daemon's "
                f"copy may be damaged (check it with `micam inspect SESSION`)")
        os.replace(partial, self.target(job, file.path))
