"""What a calibration's session and options settle before any fit, for the stages and for the
result alike: the array boards, the known intrinsics and speed of sound, where the
camera-frozen solver's c comes from, and the joint fit's board poses.

Apart from the pipeline (which defines the measurements and options these read), so that the
result's assembly (`calibration.result_assembly`) can use them without importing the pipeline
that calls it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from acquisition.contracts.rig_description import KnownIntrinsics
from kernel.air import NOMINAL_SPEED_OF_SOUND_M_S, SpeedOfSoundPrior

from .result import SpeedOfSoundFrom
from .session_data import SessionData
from .camera.speakers import RigPoseInCam0

if TYPE_CHECKING:
    from .pipeline import CalibrationOptions, Measurements


def known_intrinsics(data: SessionData,
                     options: CalibrationOptions) -> dict[str, KnownIntrinsics]:
    """The cameras' known intrinsics: the session description's, replaced by the options'."""
    known = {c.name: c.intrinsics for c in data.description.cameras if c.intrinsics is not None}
    return {**known, **(options.intrinsics or {})}


def speed_of_sound_plan(m: Measurements, options: CalibrationOptions
                        ) -> tuple[SpeedOfSoundFrom, float, float | None]:
    """Where the camera-frozen solver's c comes from, its start value and its prior std
    (None: fixed at the reference-microphone fit, or solved with the solver's default)."""
    if m.reference_fit is not None and options.speed_of_sound == "reference":
        return "reference_microphone", m.reference_fit.speed_of_sound_m_s, None
    known = known_speed_of_sound(m, options)
    if known is not None:
        return "known", known[0], known[1]
    c0 = (m.reference_fit.speed_of_sound_m_s if m.reference_fit is not None
          else NOMINAL_SPEED_OF_SOUND_M_S)
    return "solved", c0, None


def known_speed_of_sound(m: Measurements,
                         options: CalibrationOptions) -> SpeedOfSoundPrior | None:
    """The known (c, std) in m/s: the options', else the session description's air (a
    reading someone wrote down), else the session's air-sensor readings."""
    if options.speed_of_sound_prior is not None:
        return options.speed_of_sound_prior
    air = m.data.description.air
    if air is not None:
        return air.speed_of_sound_prior()
    return m.air if options.air_sensor else None


def board_indices(data: SessionData) -> tuple[list[str], np.ndarray]:
    """The array boards (sorted serials) and each microphone's index into them."""
    boards = sorted(set(data.mic_boards))
    return boards, np.array([boards.index(b) for b in data.mic_boards])


def _bundle_steps(m: Measurements) -> tuple[list[str], list[RigPoseInCam0]]:
    """The board poses of the joint fit: the located pose steps, then the reference-microphone
    step when it was located (its corners constrain the cameras too)."""
    poses = list(m.speakers.poses)
    if m.reference is not None:
        poses.append(m.reference.pose)
    return [p.step for p in poses], poses
