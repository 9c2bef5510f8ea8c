"""The simulated operator: carries out the capture's instructions by moving the simulated world."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from acquisition.contracts.instructions import Instruction, InstructionKind

from .geometry import CameraModel, RigidTransform
from .mistakes.plan import NO_MISTAKES, Mistakes
from .poses import FACING_CAMERA
from .setups import POSE_SETUP, REFERENCE_SETUP, STAND_SETUP, Setups
from .world import World


def reference_stand_position(camera: CameraModel, depth_m: float = 0.8) -> np.ndarray:
    """A stand position just outside the lower-left corner of the camera's view (camera-0 frame).

    With the rig's reference mark (the plate's corner at minimum X and Y) touching it and the
    board facing the camera, the checkerboard extends up and to the right, into the view.
    """
    ray = np.linalg.inv(camera.K) @ np.array([-20.0, camera.height + 20.0, 1.0])
    return camera.cam0_to_cam.inverse().apply(depth_m * ray / ray[2])


_SETUP_CODE = {InstructionKind.REFERENCE_AT_SPEAKER: REFERENCE_SETUP,
               InstructionKind.REFERENCE_ON_STAND: STAND_SETUP,
               InstructionKind.RIG_AT_POSE: POSE_SETUP}


class SimulatedOperator:
    """Moves the rig through a list of poses and places the reference microphone; tells
    `setups` which set-up it made (the key of the noise that follows, see sim.setups). Its
    `mistakes` are the operator's: a rig nudged after a pose's images, the reference
    microphone held further from a speaker than stated (sim.mistakes)."""

    def __init__(self, world: World, poses: Sequence[RigidTransform],
                 stand_position_m: np.ndarray, setups: Setups | None = None,
                 mistakes: Mistakes = NO_MISTAKES) -> None:
        self.world = world
        self.poses = list(poses)
        self.stand_position_m = np.asarray(stand_position_m, dtype=np.float64)
        self.setups = setups or Setups()
        self.mistakes = mistakes

    def rig_pose_on_stand(self) -> RigidTransform:
        """The rig pose with its reference mark at the stand, facing camera 0."""
        R = FACING_CAMERA
        return RigidTransform(R, self.stand_position_m - R @ self.world.rig.reference_mark_m)

    def perform(self, instruction: Instruction) -> None:
        w = self.world
        if instruction.kind is InstructionKind.REFERENCE_AT_SPEAKER:
            if instruction.speaker is None or not 0 <= instruction.speaker < w.rig.n_speakers:
                raise ValueError(f"no speaker {instruction.speaker} on the rig")
            w.set_session_progress(0.0)
            distance = self.mistakes.reference_distances_m.get(instruction.speaker)
            w.place_reference_mic(w.reference_position_at_speaker(instruction.speaker, distance),
                                  near_speaker=instruction.speaker)
        elif instruction.kind is InstructionKind.REFERENCE_ON_STAND:
            w.set_session_progress(0.0)
            w.place_reference_mic(self.stand_position_m)
            w.place_rig(self.rig_pose_on_stand())
        elif instruction.kind is InstructionKind.RIG_AT_POSE:
            if instruction.pose is None or not 0 <= instruction.pose < len(self.poses):
                raise ValueError(f"the simulated operator has no pose {instruction.pose}")
            w.set_session_progress(instruction.pose / max(len(self.poses) - 1, 1))
            w.place_reference_mic(self.stand_position_m)
            w.place_rig(self.poses[instruction.pose],
                        pose_for_bursts=self.mistakes.moved_poses.get(instruction.pose))
        else:  # pragma: no cover - every kind is handled above
            raise ValueError(f"unknown instruction {instruction.kind}")
        which = {InstructionKind.REFERENCE_AT_SPEAKER: instruction.speaker,
                 InstructionKind.RIG_AT_POSE: instruction.pose}.get(instruction.kind)
        self.setups.begin((_SETUP_CODE[instruction.kind], which or 0))
