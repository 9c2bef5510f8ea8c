"""One numbering (README, "Numbering"): a short session through the daemon, and every
instruction the operator reads (event, status, `micam watch`) names the pose or speaker by the
number of its step and of its directory on disk."""

from __future__ import annotations

import re
from contextlib import closing
from pathlib import Path

import pytest

from acquisition.contracts.protocol import CaptureEvent, InstructionEvent, ProgressEvent
from acquisition.contracts.session import SessionReader
from micam.display import format_event

from .helpers import ThreadDaemon, capture

POSES = 3
NAMED = {"pose": re.compile(r"\bpose (\d+)\b"), "reference": re.compile(r"\bspeaker (\d+)\b")}
"""How an instruction names the thing its step is numbered after."""


def _step_number(step: str) -> int:
    return int(step.split("/")[1])


def _named(step: str, text: str) -> list[int]:
    """The numbers `text` gives the pose or speaker of `step` (one, if it names it once)."""
    return [int(n) for n in NAMED[step.split("/")[0]].findall(text)]


@pytest.mark.slow
def test_instructions_name_the_number_of_their_step_and_directory(
        daemon: ThreadDaemon) -> None:
    shown: list[tuple[str, str]] = []  # (step, instruction text) as status reports them
    with daemon.client() as client, closing(client.subscribe()) as events:
        path = Path(client.request("session.start", poses=POSES)["session"]["path"])
        for _ in range(50):
            status = client.status()
            if status.session is None:
                break
            if status.step and status.instruction:
                shown.append((status.step, status.instruction))
            capture(client)
        received = []
        while (event := events.next(0.5)) is not None:
            received.append(event)
    instructions = [e for e in received if isinstance(e, InstructionEvent)]
    reader = SessionReader(path)
    assert reader.status == "complete"
    steps = reader.steps()
    poses = [s for s in steps if s.startswith("pose/")]
    assert [_step_number(s) for s in poses] == list(range(POSES))
    for step in poses:  # on disk: poses/0002-a1 for step pose/0002
        number = re.fullmatch(r"poses/(\d{4})-a\d+", steps[step].dir)
        assert number and int(number.group(1)) == _step_number(step)

    numbered = [(e.step, e.text) for e in instructions] + shown
    assert {s for s, _ in numbered if s.startswith("pose/")} == set(poses)
    for step, text in numbered:
        if "/" in step:
            assert _named(step, text) == [_step_number(step)], (step, text)
    pose_text = next(e for e in instructions if e.step == "pose/0002").text
    assert f"(poses 0-{POSES - 1})" in pose_text
    assert format_event(next(e for e in instructions if e.step == "pose/0002")) == (
        f"next: pose/0002: {pose_text}")
    ended = {e.step for e in received if isinstance(e, (CaptureEvent, ProgressEvent))}
    assert set(poses) <= ended <= set(steps)


def test_a_live_job_is_named_by_the_last_pose_it_includes(small_session: Path) -> None:
    """Poses 0-2 done: the live job is "live-to-p0002" (it was "live-p0003", read as pose 3)."""
    from acquisition.daemon.jobs import job_for_session

    job = job_for_session(small_session, "live")
    assert job.job_id.endswith(".live-to-p0002") and job.poses == 3
    assert job_for_session(small_session, "final").job_id.endswith(".final")
