"""One spelling of step ids (#18): acquisition/contracts/step_ids.py makes and reads them, the
session store's validators accept what it makes, no other package module spells one, and the
report no longer loads the imaging package to read a pose number."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import tomllib
from pathlib import Path

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

REPO = Path(__file__).resolve().parents[1]
PACKAGES = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"][
    "root_packages"]
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


STEP_ID_SPELLING = re.compile(r"(pose/|reference/([0-9]+$|\{|$)|refmic$)")
"""A string constant (or the literal part of an f-string) that spells a step id: "pose/..."
in any form, "reference/<k>", "reference/" before a placeholder, "refmic". Not
"reference/speaker0.wav" (a file of an import directory)."""

SPELLS_STEP_IDS = {
    "acquisition/contracts/step_ids.py": "the one spelling",
}


def step_id_spellings(source: str) -> list[str]:
    """The string constants of `source`'s code that spell a step id; a docstring, or any
    other string standing alone as a statement, and comments are no code."""
    tree = ast.parse(source)
    alone = {id(node.value) for node in ast.walk(tree)
             if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)}
    return [node.value for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in alone and STEP_ID_SPELLING.match(node.value)]


def test_a_hand_spelled_step_id_is_found_and_prose_is_not() -> None:
    code = ('"""Steps "pose/0003" and "refmic"."""\n'
            'a = f"pose/{i:04d}"\n'
            'b = s.startswith("pose/")\n'
            'c = f"reference/{k}"\n'
            'd = "refmic"\n'
            'e = "reference/{}"\n'
            'f = "reference/2"\n'
            '# "pose/0001"\n'
            'def g():\n    """A "pose/0001" step."""\n'
            'h = ["reference/speaker0.wav", "refmic_images", "pose", "the refmic step"]\n')
    assert sorted(step_id_spellings(code)) == ["pose/", "pose/", "reference/", "reference/2",
                                               "reference/{}", "refmic"]


@pytest.mark.slow
def test_no_package_module_but_step_ids_spells_a_step_id() -> None:
    """#18 found the step ids spelled by hand in some twenty places; each now calls
    acquisition.contracts.step_ids (pose_step, pose_index, is_pose_step, reference_step,
    is_reference_step, REFMIC_STEP)."""
    found = {str(path.relative_to(REPO)): spellings
             for top in PACKAGES for path in sorted((REPO / top).rglob("*.py"))
             if (spellings := step_id_spellings(path.read_text()))}
    assert {p: s for p, s in found.items() if p not in SPELLS_STEP_IDS} == {}
    assert SPELLS_STEP_IDS.keys() <= found.keys()  # the exceptions still need to be


@pytest.mark.slow
def test_the_report_reads_pose_numbers_without_the_imaging_package() -> None:
    """calibration.report imported imaging (and scipy.signal) for pose_index
    alone: ~0.45 s of every CLI start. A fresh interpreter shows what importing it loads."""
    loaded = subprocess.run(
        [sys.executable, "-c", "import sys, calibration.report; print(*sorted(sys.modules))"],
        cwd=REPO, capture_output=True, text=True, check=True).stdout.split()
    assert "calibration.report" in loaded
    assert [m for m in loaded if m.startswith(("imaging", "scipy.signal"))] == []
