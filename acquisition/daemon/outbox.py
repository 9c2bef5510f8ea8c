"""The durable job outbox: one small JSON file per calibration job, rewritten atomically.

The zguide's Titanic pattern: a job is on disk before any worker hears of it, and every state
change (pending -> leased -> done/failed) is written (temporary name, fsync, rename) before it
is acted on. A daemon restart therefore loses no job: `Outbox.load` turns every job that was
leased when the daemon stopped back into pending, and the next lease gets a higher `attempt`,
which fences off any result still coming from the old one.

Live jobs are many and short-lived: a newer live job of a session supersedes a pending older
one, and their files are deleted once finished (their outcome is in the events and in the
session's calibration/live.json). Final jobs stay, as the record that a session's result was
stored, by which attempt, with which checksum.
"""

from __future__ import annotations

import logging
from datetime import datetime
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, ValidationError

from ..session._atomic import fsync_dir, write_atomic
from .job_messages import JobFile, JobKind, JournalPrefix
from .protocol import utc_now

log = logging.getLogger("micam.daemon")

JobState = Literal["pending", "leased", "done", "failed"]


class JobRecord(BaseModel):
    """A job as the outbox keeps it."""

    model_config = ConfigDict(extra="forbid")

    job_id: str
    kind: JobKind
    session_id: str
    session_path: str
    poses: int
    journal: JournalPrefix
    files: list[JobFile]
    state: JobState = "pending"
    attempt: int = 0
    worker: str | None = None
    created_utc: datetime
    updated_utc: datetime
    result_sha256: str | None = None
    reason: str = ""

    def allowed(self, path: str) -> int | None:
        """How many bytes of `path` a worker of this job may fetch (None: not this job's)."""
        if path == "journal.jsonl":
            return self.journal.bytes
        for file in self.files:
            if file.path == path:
                return file.bytes
        return None


class Outbox:
    """The jobs of `directory`, in memory and on disk (one `<job_id>.json` per job)."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.jobs: dict[str, JobRecord] = {}

    def load(self) -> list[JobRecord]:
        """Read every job file; jobs leased before a restart become pending. Returns them."""
        requeued = []
        for path in sorted(self.directory.glob("*.json")):
            try:
                job = JobRecord.model_validate_json(path.read_bytes())
            except (OSError, ValidationError) as exc:
                log.error("ignoring the unreadable job file %s: %s", path, exc)
                continue
            self.jobs[job.job_id] = job
            if job.state == "leased":
                self.update(job, state="pending", worker=None,
                            reason=f"the daemon restarted during attempt {job.attempt}")
                requeued.append(job)
        return requeued

    def add(self, job: JobRecord) -> None:
        self.jobs[job.job_id] = job
        self._write(job)

    def update(self, job: JobRecord, **fields: object) -> JobRecord:
        """Change fields of `job` on disk, then in memory; return the new record."""
        new = job.model_copy(update={**fields, "updated_utc": utc_now()})
        self._write(new)
        self.jobs[new.job_id] = new
        return new

    def remove(self, job: JobRecord) -> None:
        self.jobs.pop(job.job_id, None)
        self._path(job.job_id).unlink(missing_ok=True)
        fsync_dir(self.directory)

    def pending(self) -> list[JobRecord]:
        """Pending jobs, oldest first (final jobs before live ones created at the same time)."""
        return sorted((j for j in self.jobs.values() if j.state == "pending"),
                      key=lambda j: (j.created_utc, j.kind != "final"))

    def _path(self, job_id: str) -> Path:
        return self.directory / f"{job_id}.json"

    def _write(self, job: JobRecord) -> None:
        text = job.model_dump_json(indent=1).encode()
        write_atomic(self._path(job.job_id), lambda fh: fh.write(text), replace=True)
