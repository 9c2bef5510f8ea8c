"""The capture sequencer: the steps of a calibration capture, run on whatever hardware is given.

It knows boards only through `daq.SyncGroup`, cameras through `acquisition.contracts.camera.Camera` and
the person moving the rig through `acquisition.contracts.instructions.Operator`, so the same code drives real
boards, simulated ones and emulated USB devices.

Steps, in order (paper IV-C):
1. `reference/<k>` for every speaker k: the reference microphone ~2 mm from speaker k, k's
   burst recorded on every channel;
2. `refmic`: the reference microphone on its stand, touched by the rig's reference mark, one
   image from every camera (locates the reference microphone for the speed of sound);
3. `pose/<nnnn>` for every rig pose: one image from every camera, a reading of the air sensor
   (`air.json`, when there is one), then every speaker's burst recorded on every channel (the
   reference microphone stays on its stand).

A step is atomic: if anything fails inside it, its attempt is journaled as abandoned (with the
reason) and the error propagates; the session stays open (it reads as interrupted) and the whole
step is captured again on resume, into a new attempt directory. A process killed inside a step
leaves the attempt open, which resume turns into an abandoned one.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from daq import SyncGroup, volts_to_codes

from acquisition.contracts.camera import Camera
from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.instructions import Instruction, InstructionKind, Operator
from acquisition.contracts.session import StepRecorder
from acquisition.contracts.step_ids import REFMIC_STEP, pose_step, reference_step
from kernel.air import AIR_FILE, AirSensor
from kernel.stimulus import mls_burst


@dataclass(frozen=True)
class Step:
    """One atomic capture step: its journal id and what the operator must set up first."""

    id: str
    instruction: Instruction


@dataclass(frozen=True)
class Progress:
    """Reported after every completed step."""

    done: int
    total: int
    step: str


def plan_steps(config: CaptureConfig) -> list[Step]:
    """Every step of a capture with `config`, in order. A pose or speaker has one number, from
    0, in its step id, its instruction's field and its text (README, "Numbering")."""
    steps = [
        Step(reference_step(s.index), Instruction(
            kind=InstructionKind.REFERENCE_AT_SPEAKER, speaker=s.index,
            text=f"Hold the reference microphone about "
                 f"{config.reference.distance_from_speaker_m * 1000:.0f} mm in front of "
                 f"speaker {s.index}."))
        for s in config.speakers
    ]
    steps.append(Step(REFMIC_STEP, Instruction(
        kind=InstructionKind.REFERENCE_ON_STAND,
        text="Put the reference microphone on its stand just outside the camera view and touch "
             "it with the rig's reference mark, the board in view.")))
    steps += [
        Step(pose_step(i), Instruction(
            kind=InstructionKind.RIG_AT_POSE, pose=i,
            text=f"Hold the rig still at pose {i} (poses 0-{config.n_poses - 1}), in view of "
                 "the cameras."))
        for i in range(config.n_poses)
    ]
    return steps


class CaptureSequencer:
    """Runs (or continues) the capture of one session."""

    def __init__(
        self,
        config: CaptureConfig,
        group: SyncGroup,
        cameras: Sequence[Camera],
        operator: Operator,
        writer: StepRecorder,
        on_progress: Callable[[Progress], None] | None = None,
        camera_timeout_s: float = 2.0,
        air_sensor: AirSensor | None = None,
    ) -> None:
        names = [c.name for c in cameras]
        if names != [c.name for c in config.cameras]:
            raise ValueError(f"cameras {names} do not match the configuration's "
                             f"{[c.name for c in config.cameras]}")
        self.config = config
        self.group = group
        self.cameras = list(cameras)
        self.operator = operator
        self.writer = writer
        self.on_progress = on_progress
        self.camera_timeout_s = camera_timeout_s
        self.air_sensor = air_sensor
        self._board_index = {b.serial: i for i, b in enumerate(config.boards)}
        self._burst_v = config.burst.amplitude_v * np.tile(mls_burst(config.burst.mls_order),
                                                           config.burst.periods)

    def remaining_steps(self) -> list[Step]:
        done = self.writer.completed_steps()
        return [s for s in plan_steps(self.config) if s.id not in done]

    def run(self) -> None:
        """Capture every step not yet completed, then close the session as complete."""
        steps = plan_steps(self.config)
        done = self.writer.completed_steps()
        self.group.configure(self.config.scan_configs())
        for step in steps:
            if step.id in done:
                continue
            self.operator.perform(step.instruction)
            self._capture(step)
            if self.on_progress is not None:
                self.on_progress(Progress(len(self.writer.completed_steps()), len(steps),
                                          step.id))
        self.writer.stop("success")

    def _capture(self, step: Step) -> None:
        kind = step.instruction.kind
        self.writer.begin_step(step.id)
        try:
            self._capture_into_open_step(step, kind)
        except Exception as exc:
            self.writer.abandon_step(step.id, f"{type(exc).__name__}: {exc}")
            raise
        self.writer.end_step(step.id)

    def _capture_into_open_step(self, step: Step, kind: InstructionKind) -> None:
        if kind is InstructionKind.REFERENCE_AT_SPEAKER:
            self._record_speaker(step.id, step.instruction.speaker or 0)
        elif kind is InstructionKind.REFERENCE_ON_STAND:
            self._take_images(step.id)
        else:
            self._take_images(step.id)
            if self.air_sensor is not None:
                reading = self.air_sensor.read()
                self.writer.write_json(step.id, AIR_FILE, reading.model_dump(mode="json"))
            for speaker in self.config.speakers:
                self._record_speaker(step.id, speaker.index)

    def _take_images(self, step_id: str) -> None:
        for camera in self.cameras:
            frame = camera.grab(self.camera_timeout_s)
            self.writer.write_image(step_id, f"{camera.name}.png", frame.image,
                                    meta={"device_id": camera.device_id})

    def _record_speaker(self, step_id: str, speaker_index: int) -> None:
        speaker = self.config.speakers[speaker_index]
        board = self._board_index[speaker.board]
        entry = self.config.boards[board]
        column = [c.channel for c in entry.outputs].index(speaker.output_channel)
        volts = np.zeros((self.config.burst.n_samples, len(entry.outputs)))
        start = self.config.burst.pre_samples
        volts[start: start + len(self._burst_v), column] = self._burst_v
        codes = volts_to_codes(volts, entry.outputs[column].range_v)
        recording = self.group.acquire({board: codes})
        self.writer.write_recording(
            step_id, f"speaker_{speaker_index}.wav", recording.codes,
            round(self.config.sample_rate_hz),
            meta={"speaker": speaker_index, "burst_start_sample": start},
        )
