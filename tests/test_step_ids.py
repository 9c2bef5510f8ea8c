"""One spelling of step ids (#18): acquisition/contracts/step_ids.py makes and reads them, the
session store's validators accept what it makes, and no other package module spells one."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import TypeAdapter, ValidationError

from acquisition.contracts.safe_names import is_step_id
from acquisition.contracts.session import attempt_dir
from acquisition.contracts.session._layout import attempt_of_dir
from acquisition.contracts.session._models import StepId
from acquisition.contracts.step_ids import (
    REFMIC_STEP,
    is_pose_step,
    is_reference_step,
    pose_index,
    pose_step,
    reference_step,
)

NOT_POSE_STEPS = ["pose/x", "poses/0003", "pose/3", "pose/00003", "pose/-001", "pose/",
                  "pose/0003/a", "pose/0003-a1", "pose/\u0660\u0660\u0660\u0663",
                  "reference/2", REFMIC_STEP, "", "Pose/0003"]
"""Strings that are no pose step id (Arabic-Indic digits too, though int() reads them)."""


def test_a_pose_step_round_trips_from_zero() -> None:
    assert pose_step(0) == "pose/0000" and pose_step(3) == "pose/0003"
    assert pose_step(12345) == "pose/12345"
    for index in (0, 1, 9, 10, 999, 9999, 10000, 123456):
        assert pose_index(pose_step(index)) == index and is_pose_step(pose_step(index))
    assert pose_step(np.int64(7)) == "pose/0007"  # a pose number taken from an array


@pytest.mark.parametrize("step", NOT_POSE_STEPS)
def test_anything_else_is_no_pose_step(step: str) -> None:
    assert pose_index(step) is None and not is_pose_step(step)


def test_a_reference_step_names_its_speaker_unpadded() -> None:
    assert reference_step(0) == "reference/0" and reference_step(12) == "reference/12"
    assert all(is_reference_step(reference_step(k)) for k in range(20))
    for step in ("reference/02", "reference/x", "references/2", "reference/", "reference/-1",
                 "pose/0002", REFMIC_STEP):
        assert not is_reference_step(step), step


def test_no_step_has_a_negative_or_fractional_number() -> None:
    for make in (pose_step, reference_step):
        with pytest.raises(ValueError, match="starts at 0"):
            make(-1)
        with pytest.raises(TypeError):
            make(1.0)  # type: ignore[arg-type]


def test_the_store_accepts_every_id_made_here_and_files_it_where_the_docstring_says() -> None:
    """The validators (safe_names.is_step_id, the journal's StepId) stay where they are; what
    this module makes must pass them, and attempt_dir/attempt_of_dir map it both ways."""
    adapter = TypeAdapter(StepId)
    made = [reference_step(0), reference_step(11), REFMIC_STEP, pose_step(0), pose_step(3),
            pose_step(19), pose_step(10000)]
    for step in made:
        assert is_step_id(step) and adapter.validate_python(step) == step
        for attempt in (1, 2, 13):
            assert attempt_of_dir(attempt_dir(step, attempt)) == (step, attempt)
    assert attempt_dir(pose_step(3), 1) == "poses/0003-a1"
    assert attempt_dir(reference_step(2), 1) == "references/2-a1"
    assert attempt_dir(REFMIC_STEP, 1) == "refmic-a1"
    for step in ("poses/0003/x/y", "pose/ 3", "../pose/0003"):  # rejected by both
        assert not is_step_id(step) and not is_pose_step(step)
        with pytest.raises(ValidationError):
            adapter.validate_python(step)


@pytest.mark.parametrize("directory", ["poses/0003", "pose/0003-a1", "poses/0003-a01",
                                       "poses/0003-a", "a/poses/0003-a1", "poses/-a1",
                                       "journal.jsonl"])
def test_a_path_no_attempt_has_gives_none(directory: str) -> None:
    assert attempt_of_dir(directory) is None
