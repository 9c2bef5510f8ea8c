"""A job's calibration on the worker's copy of the session.

final: the full pipeline (`calibration.pipeline.calibrate`, joint fit included unless switched
off) on the closed session; the result is result.json's bytes and the report `micam calibrate`
writes (`calibration.report.write_report`: report.md and its figures), by file name. live: the quick camera-frozen
solve of the poses so far (`measure` + `solve`, no joint fit: seconds, not minutes) turned into
a `LiveUpdate`. Either raises ValueError (CalibrationInputError and the stages' own errors)
with a message that says what is missing.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from acquisition.contracts.job_messages import Job, LiveUpdate

from ..pipeline import CalibrationOptions, WorkMemo, calibrate, measure, solve
from ..report import write_report
from .live import live_update


@dataclass(frozen=True)
class Final:
    """A final job's answer: result.json's bytes, and the report's files by name."""

    result: bytes
    report: dict[str, bytes]


def compute(job: Job, session: Path, joint: bool, on_stage: Callable[[str], None],
            memo: WorkMemo | None = None) -> Final | LiveUpdate:
    """Run `job` on the session copy at `session` (see the module docstring); `memo`: the
    worker's memo of detections and delays, kept across its jobs."""
    if job.kind == "final":
        run = calibrate(session, CalibrationOptions(joint=joint, memo=memo),
                        on_stage)
        on_stage("report")
        with tempfile.TemporaryDirectory(prefix="micam-report-") as tmp:
            write_report(run, Path(tmp))
            report = {p.name: p.read_bytes() for p in sorted(Path(tmp).iterdir())
                      if p.is_file()}
        return Final(run.result.model_dump_json(indent=1).encode(), report)
    options = CalibrationOptions(allow_interrupted=True, joint=False, memo=memo)
    m = measure(session, options, on_stage)
    on_stage("solver")
    return live_update(job.session_id, m, solve(m, options))
