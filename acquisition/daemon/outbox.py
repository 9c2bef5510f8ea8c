"""The durable job outbox: one small JSON file per calibration job, rewritten atomically.

The zguide's Titanic pattern: a job is on disk before any worker hears of it, and a lease
(pending -> leased) is written (temporary name, fsync, rename) before the job is sent. A daemon
restart therefore loses no job: `Outbox.load` turns every job that was leased when the daemon
stopped back into pending, and the next lease gets a higher `attempt`, which fences off any
result still coming from the old one.

When the outbox's filesystem refuses a write (full, read-only, failing), nothing is lost:

- a lease is never sent (`update` raises; the job stays pending and is offered again later);
- the other changes (a new job, pending again, done, failed) are kept in memory and written
  by `flush` once the disk takes them (`record`). Each is what a restart concludes anyway, or
  what the session's own files say: a job whose record still reads leased becomes pending,
  and a result already stored is found again when the job is done once more.

Live jobs are many and short-lived: a newer live job of a session supersedes a pending older
one, and their files are deleted once finished (their outcome is in the events and in the
session's calibration/live.json). A final job's record stays as the record that a session's
result was stored, by which attempt, with which checksum, until `prune` removes finished
records older than the configured number of days.

Every record is validated when read: its ids are safe names (acquisition.safe_names), its
file is `<job_id>.json`, and its session is `<session_root>/<session_id>`, so that an edited
or planted job file can neither write outside the outbox nor point the broker and the file
server at another directory.
"""

from __future__ import annotations

import logging
from datetime import datetime
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, ValidationError

from acquisition.contracts.safe_names import SafeName
from acquisition.contracts.session import fsync_dir, remove_partials, write_atomic
from acquisition.contracts.job_messages import JobFile, JobKind, JournalPrefix
from acquisition.contracts.protocol import utc_now

log = logging.getLogger("micam.daemon")

JobState = Literal["pending", "leased", "done", "failed"]


class JobRecord(BaseModel):
    """A job as the outbox keeps it."""

    model_config = ConfigDict(extra="forbid")

    job_id: SafeName
    kind: JobKind
    session_id: SafeName
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
    not_before_utc: datetime | None = None  # a pending job waiting out a retry delay

    def allowed(self, path: str) -> int | None:
        """How many bytes of `path` a worker of this job may fetch (None: not this job's)."""
        if path == "journal.jsonl":
            return self.journal.bytes
        for file in self.files:
            if file.path == path:
                return file.bytes
        return None


class Outbox:
    """The jobs of `directory`, in memory and on disk (one `<job_id>.json` per job), of the
    sessions under `session_root`."""

    def __init__(self, directory: Path, session_root: Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.session_root = Path(session_root)
        self.jobs: dict[str, JobRecord] = {}
        self.unsaved: set[str] = set()  # jobs whose latest change is not on disk yet

    def load(self) -> list[JobRecord]:
        """Read every job file; jobs leased before a restart become pending. Returns them.
        (A `.partial` file left by a crash is deleted: the daemon is the outbox's one writer.)"""
        remove_partials(self.directory)
        requeued = []
        for path in sorted(self.directory.glob("*.json")):
            try:
                job = JobRecord.model_validate_json(path.read_bytes())
                self._check(job, path)
            except (OSError, ValidationError, ValueError) as exc:
                log.error("ignoring the job file %s, which is not a job of this daemon: %s",
                          path, exc)
                continue
            self.jobs[job.job_id] = job
            if job.state == "leased":
                self.record(job, state="pending", worker=None,
                            reason=f"the daemon restarted during attempt {job.attempt}")
                requeued.append(job)
        return requeued

    def _check(self, job: JobRecord, path: Path) -> None:
        if path.name != f"{job.job_id}.json":
            raise ValueError(f"it holds job {job.job_id!r}, not {path.stem!r}")
        if Path(job.session_path) != self.session_root / job.session_id:
            raise ValueError(f"its session {job.session_path!r} is not "
                             f"{self.session_root / job.session_id}")

    def update(self, job: JobRecord, **fields: object) -> JobRecord:
        """Change fields of `job` on disk, then in memory; return the new record. OSError if
        the disk refuses (memory unchanged): for changes that must be durable (a lease)."""
        new = job.model_copy(update={**fields, "updated_utc": utc_now()})
        self._write(new)
        self.jobs[new.job_id] = new
        self.unsaved.discard(new.job_id)
        return new

    def record(self, job: JobRecord, **fields: object) -> JobRecord:
        """Change fields of `job` (or add it); on disk now if the disk takes it, else by the
        next `flush` (see the module docstring: only for changes that may wait)."""
        new = job.model_copy(update={**fields, "updated_utc": utc_now()})
        self.jobs[new.job_id] = new
        try:
            self._write(new)
        except OSError as exc:
            log.error("cannot write the job file of %s (%s); keeping it in memory until the "
                      "outbox %s takes writes again", new.job_id, exc, self.directory)
            self.unsaved.add(new.job_id)
        else:
            self.unsaved.discard(new.job_id)
        return new

    def add(self, job: JobRecord) -> None:
        self.record(job)

    def flush(self) -> bool:
        """Write the records kept in memory; True when nothing is left unsaved."""
        for job_id in sorted(self.unsaved):
            job = self.jobs.get(job_id)
            try:
                if job is not None:
                    self._write(job)
            except OSError:
                return False
            self.unsaved.discard(job_id)
        return True

    def remove(self, job: JobRecord) -> None:
        self.jobs.pop(job.job_id, None)
        self.unsaved.discard(job.job_id)
        try:
            self._path(job.job_id).unlink(missing_ok=True)
            fsync_dir(self.directory)
        except OSError as exc:  # a stale file reads as a job to run again: harmless
            log.error("cannot remove the job file of %s: %s", job.job_id, exc)

    def prune(self, finished_before: datetime) -> list[str]:
        """Remove the records of jobs done or failed before `finished_before`; their ids."""
        old = [j for j in self.jobs.values()
               if j.state in ("done", "failed") and j.updated_utc < finished_before]
        for job in old:
            self.remove(job)
        return [j.job_id for j in old]

    def pending(self) -> list[JobRecord]:
        """Pending jobs, oldest first (final jobs before live ones created at the same time)."""
        return sorted((j for j in self.jobs.values() if j.state == "pending"),
                      key=lambda j: (j.created_utc, j.kind != "final"))

    def _path(self, job_id: str) -> Path:
        return self.directory / f"{job_id}.json"

    def _write(self, job: JobRecord) -> None:
        text = job.model_dump_json(indent=1).encode()
        write_atomic(self._path(job.job_id), lambda fh: fh.write(text), replace=True)
