"""The ids of a session's steps: the one place that spells them.

A calibration capture has three kinds of step (`acquisition.sequencer`, `acquisition.importer`):

- `reference_step(k)`, "reference/2": the reference microphone in front of speaker k;
- `REFMIC_STEP`, "refmic": the reference microphone on its stand, touched by the rig's mark;
- `pose_step(i)`, "pose/0003": the rig held still at pose i.

Numbering (README, "Numbering"): a pose or speaker number starts at 0 and is the same number
everywhere, so pose 3 is step "pose/0003", `pose=3` in its instruction and "pose 3" on the
operator's page. A pose number is written with at least four digits, zero-padded; a speaker
number without padding. Only the canonical spellings are step ids of these kinds: "pose/3",
"pose/x" and "poses/0003" are not pose steps, and negative numbers have no step.

On disk, an attempt at a step is a directory named by
`acquisition.contracts.session.attempt_dir`: the group gets an "s" and the attempt number
(from 1) a "-a" suffix, so attempt 1 of "pose/0003" is "poses/0003-a1", of "reference/2"
"references/2-a1" and of "refmic" "refmic-a1" (`session._layout.attempt_of_dir` reads a
directory back into its step and attempt).

Every id here is a valid step id of the session store (`safe_names.is_step_id`, which the
journal's records validate); this module makes ids, the store checks whatever arrives.
It imports only the standard library, so anything (a calibration worker, the CLI) may use
it for free.
"""

from __future__ import annotations

import operator
import re
from typing import SupportsIndex

_POSE = "pose"
_REFERENCE = "reference"
REFMIC_STEP = "refmic"
"""The step that locates the reference microphone on its stand (camera images only)."""

_POSE_RE = re.compile(rf"{_POSE}/([0-9]{{4,}})")
_REFERENCE_RE = re.compile(rf"{_REFERENCE}/([0-9]+)")


def _number(index: SupportsIndex, what: str) -> int:
    """`index` checked: a pose or speaker number is an integer from 0 (a Python or a numpy
    integer; a float raises TypeError)."""
    number = operator.index(index)
    if number < 0:
        raise ValueError(f"a {what} number starts at 0, not {number}")
    return number


def pose_step(index: SupportsIndex) -> str:
    """The step id of pose `index` (from 0): pose_step(3) == "pose/0003"."""
    return f"{_POSE}/{_number(index, 'pose'):04d}"


def pose_index(step: str) -> int | None:
    """The pose number of a pose step ("pose/0007" -> 7), or None for any other step."""
    match = _POSE_RE.fullmatch(step)
    if match is None:
        return None
    index = int(match[1])
    return index if pose_step(index) == step else None  # "pose/00007" is not pose 7's id


def is_pose_step(step: str) -> bool:
    """Whether `step` is the step id of a pose ("pose/0003")."""
    return pose_index(step) is not None


def reference_step(speaker: SupportsIndex) -> str:
    """The step id of the reference recording of speaker `speaker` (from 0): "reference/2"."""
    return f"{_REFERENCE}/{_number(speaker, 'speaker')}"


def is_reference_step(step: str) -> bool:
    """Whether `step` is the step id of a speaker's reference recording ("reference/2", not
    "reference/02")."""
    match = _REFERENCE_RE.fullmatch(step)
    return match is not None and reference_step(int(match[1])) == step
