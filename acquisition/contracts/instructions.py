"""What the capture asks of the person (or robot) who moves the rig and the reference microphone.

The sequencer never moves anything itself: before each step it hands an `Instruction` to an
`Operator` and waits until the operator says it is done. The daemon's operator relays it to
the CLI; the simulated operator moves the simulated world.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Protocol, runtime_checkable

from pydantic import BaseModel, ConfigDict


class InstructionKind(StrEnum):
    """The physical set-up a capture step needs."""

    REFERENCE_AT_SPEAKER = "reference_at_speaker"
    """Hold the reference microphone about 2 mm in front of speaker `speaker`."""

    REFERENCE_ON_STAND = "reference_on_stand"
    """Put the reference microphone on its stand just outside the camera's view and touch it
    with the rig's reference mark, the board in view (paper IV-C)."""

    RIG_AT_POSE = "rig_at_pose"
    """Hold the rig still at a new pose `pose` in view of the cameras (the reference microphone
    stays on its stand)."""


class Instruction(BaseModel):
    """One request to the operator."""

    model_config = ConfigDict(frozen=True)

    kind: InstructionKind
    speaker: int | None = None
    pose: int | None = None
    text: str


@runtime_checkable
class Operator(Protocol):
    """Carries out instructions; returns when the set-up is ready."""

    def perform(self, instruction: Instruction) -> None: ...
