"""A job's calibration on the worker's copy of the session.

final: the full pipeline (`calibration.pipeline.calibrate`, joint fit included unless switched
off) on the closed session; the result is result.json's bytes. live: the quick camera-frozen
solve of the poses so far (`measure` + `solve`, no joint fit: seconds, not minutes) turned into
a `LiveUpdate`. Either raises ValueError (CalibrationInputError and the stages' own errors)
with a message that says what is missing.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from acquisition.contracts.job_messages import Job, LiveUpdate

from ..pipeline import CalibrationOptions, WorkMemo, calibrate, measure, solve
from .live import live_update


def compute(job: Job, session: Path, joint: bool, on_stage: Callable[[str], None],
            memo: WorkMemo | None = None) -> bytes | LiveUpdate:
    """Run `job` on the session copy at `session` (see the module docstring); `memo`: the
    worker's memo of detections and delays, kept across its jobs."""
    if job.kind == "final":
        run = calibrate(session, CalibrationOptions(joint=joint, memo=memo),
                        on_stage)
        return run.result.model_dump_json(indent=1).encode()
    options = CalibrationOptions(allow_interrupted=True, joint=False, memo=memo)
    m = measure(session, options, on_stage)
    on_stage("solver")
    return live_update(job.session_id, m, solve(m, options))
