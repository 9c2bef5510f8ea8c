"""Making a calibration job from a session: its files and journal prefix, as the journal says.

A job names exactly what its worker may fetch: the files of the completed steps (with the
journal's sizes and checksums) and the journal up to now. The journal is append-only, so the
prefix a job names never changes even while the capture goes on.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from acquisition.contracts.session import JOURNAL_NAME, SessionReader
from acquisition.contracts.step_ids import is_pose_step, pose_index
from acquisition.contracts.job_messages import JobFile, JobKind, JournalPrefix
from .outbox import JobRecord
from acquisition.contracts.protocol import utc_now


def _journal_prefix(session: Path) -> JournalPrefix:
    data = (session / JOURNAL_NAME).read_bytes()
    return JournalPrefix(bytes=len(data), sha256=hashlib.sha256(data).hexdigest())


def job_for_session(session: Path, kind: JobKind) -> JobRecord:
    """A pending job for the session at `session` as it stands now (call between steps)."""
    journal = _journal_prefix(session)
    reader = SessionReader(session)
    steps = reader.steps()
    poses = sum(is_pose_step(s) for s in steps)
    files = [JobFile(path=f.path, bytes=f.bytes, sha256=f.sha256)
             for record in steps.values() for f in record.files.values()]
    last = max((i for s in steps if (i := pose_index(s)) is not None), default=None)
    # a live job is named by the last pose it includes ("live-to-p0003": poses 0 to 3, the
    # step numbering of README "Numbering"), not by its count of poses
    live = "live-none" if last is None else f"live-to-p{last:04d}"
    job_id = f"{reader.session_id}.{'final' if kind == 'final' else live}"
    now = utc_now()
    return JobRecord(job_id=job_id, kind=kind, session_id=reader.session_id,
                     session_path=str(session), poses=poses, journal=journal, files=files,
                     created_utc=now, updated_utc=now)
