"""The crash-safe session store: a directory per session, an fsync'd journal, atomic files.

`SessionWriter` records a capture step by step and resumes it after a crash; `SessionReader`
gives calibration the completed steps. `write_atomic` and `sha256_file` are the one atomic
write and the one file hash of micam (every result, figure and JSON file goes through them). The format is documented in docs/session-format.md.
"""

from ._atomic import (
    FileDigest,
    fsync_dir,
    partial_path,
    remove_partials,
    sha256_file,
    write_atomic,
)
from ._journal import JOURNAL_NAME, journal_records
from ._models import (
    SCHEMA_VERSION,
    FileRecord,
    FileWritten,
    Record,
    SessionError,
    SessionExistsError,
    SessionManifest,
    SessionResume,
    SessionStart,
    SessionStop,
    StepAbandoned,
    StepBegin,
    StepEnd,
    StepRecord,
)
from ._reader import SessionReader
from ._recorder import StepRecorder
from ._writer import MANIFEST_NAME, SessionWriter, attempt_dir

__all__ = [
    "JOURNAL_NAME",
    "FileDigest",
    "fsync_dir",
    "partial_path",
    "remove_partials",
    "sha256_file",
    "write_atomic",
    "MANIFEST_NAME",
    "SCHEMA_VERSION",
    "FileRecord",
    "FileWritten",
    "Record",
    "SessionError",
    "SessionExistsError",
    "SessionManifest",
    "SessionReader",
    "SessionResume",
    "SessionStart",
    "SessionStop",
    "SessionWriter",
    "StepAbandoned",
    "StepBegin",
    "StepEnd",
    "StepRecord",
    "StepRecorder",
    "attempt_dir",
    "journal_records",
]
