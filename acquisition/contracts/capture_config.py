"""The capture configuration: what hardware records what, frozen into every session's manifest.

It says which column of a recording is which microphone (or the reference microphone), the
volts per code of each column, which output drives which speaker, the burst, the rig and the
cameras. Calibration reads none of the hardware in it: it reads the rig and array description
that `CaptureConfig.description` derives (acquisition/contracts/rig_description.py). Every
model refuses unknown keys (ConfigModel), so a misspelt key of a hand-written
`[hardware.capture]` is an error.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, model_validator

from daq import CODE_FULL_SCALE, InputChannel, OutputChannel, ScanConfig
from kernel.stimulus import mls_length

from .config_model import ConfigModel, describe_problems
from .rig_description import (
    BurstLayout,
    CameraDescription,
    ChannelGroup,
    DescriptionError,
    ReferenceMicrophone,
    RigArrayDescription,
    RigDescription,
)
from .session import SessionError


class BoardEntry(ConfigModel):
    """One board of the sync group (the first is the clock and trigger master)."""

    model: str
    serial: str
    inputs: tuple[InputChannel, ...]
    outputs: tuple[OutputChannel, ...] = ()


class ColumnEntry(ConfigModel):
    """One column of every recording: where it comes from and what it is."""

    board: str = Field(description="serial of the board")
    channel: int
    range_v: float
    role: Literal["mic", "reference"]
    mic_id: int | None = None

    @property
    def volts_per_code(self) -> float:
        return self.range_v / CODE_FULL_SCALE


def column_name(role: str, mic_id: int | None, board: str, channel: int) -> str:
    """How a person names a recording column: "mic 12 (board S1 ch 3)", or "reference mic
    (board S4 ch 0)": the microphone by the id result.json gives it, then the board's input
    (README, "Numbering": one number per microphone, whatever its column)."""
    what = "reference mic" if role == "reference" else f"mic {mic_id}"
    return f"{what} (board {board} ch {channel})"


class SpeakerEntry(ConfigModel):
    """A rig speaker: the output that drives it and its position in the rig frame (metres)."""

    index: int
    board: str
    output_channel: int
    rig_position_m: tuple[float, float, float]


class ReferenceMicEntry(ConfigModel):
    """The reference microphone: its input column and its distance from a speaker during the
    reference recordings (paper IV-C)."""

    board: str
    channel: int
    distance_from_speaker_m: float = 0.002


class BurstConfig(ConfigModel):
    """The MLS burst each speaker plays: `pre_samples` of silence, `periods` periods of an MLS
    of `mls_order` at `amplitude_v` volts back to back, then `post_samples` of recording while
    it dies away.

    Why more than one period: after the first, every microphone hears the periodic steady
    state (the direct sound and every reflection of a period arrive within it), so one period
    correlated circularly against the reference's is exactly the periodic impulse response: a
    room's reflections are clean pulses that leave the direct one alone, and the sequence's
    flat spectrum costs no precision (calibration.acoustic.delay_estimation). One period (the
    default, and what sessions recorded before it existed hold) is a burst whose reflections bias
    delays by tens of nanoseconds in a room."""

    mls_order: int = Field(default=14, ge=4, le=20)
    amplitude_v: float = Field(default=1.0, gt=0, le=10)
    pre_samples: int = Field(default=512, ge=0)
    post_samples: int = Field(default=2048, ge=0)
    periods: int = Field(default=1, ge=1, le=8)

    @property
    def n_samples(self) -> int:
        """Length of one recording, samples per channel."""
        return self.pre_samples + self.periods * mls_length(self.mls_order) + self.post_samples


RigEntry = RigDescription
"""The calibration rig of a capture: the rig of the calibration's description (one model, so
that a capture states its board's colours and tolerances exactly as an import does)."""


class CameraEntry(ConfigModel):
    """A camera of the session: its name and the identifier of the device that took it."""

    name: str
    device_id: str


class CaptureConfig(ConfigModel):
    """Everything a capture session needs to know about its hardware and its plan."""

    schema_version: Literal[1] = 1
    sample_rate_hz: float = Field(gt=0)
    boards: tuple[BoardEntry, ...]
    columns: tuple[ColumnEntry, ...]
    speakers: tuple[SpeakerEntry, ...]
    reference: ReferenceMicEntry
    burst: BurstConfig = BurstConfig()
    rig: RigEntry
    cameras: tuple[CameraEntry, ...]
    n_poses: int = Field(ge=1)

    @model_validator(mode="after")
    def _consistent(self) -> CaptureConfig:
        inputs = [(b.serial, c.channel) for b in self.boards for c in b.inputs]
        cols = [(c.board, c.channel) for c in self.columns]
        if cols != inputs:
            raise ValueError("columns must list every board input, board after board, in order")
        outputs = {(b.serial, c.channel) for b in self.boards for c in b.outputs}
        for s in self.speakers:
            if (s.board, s.output_channel) not in outputs:
                raise ValueError(
                    f"speaker {s.index} is wired to output {s.output_channel} of board {s.board}, "
                    "which is not configured as an output"
                )
        if (self.reference.board, self.reference.channel) not in inputs:
            raise ValueError("the reference microphone's channel is not a configured input")
        problems = self._calibration_problems()
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def _calibration_problems(self) -> list[str]:
        """What would keep calibration from reading the capture (its description)."""
        problems = []
        for k, s in enumerate(self.speakers):
            if s.index != k:
                problems.append(f"speakers[{k}].index: {s.index}; list the speakers in index "
                                f"order from 0 (write index = {k})")
            elif k < len(self.rig.speakers_m) and tuple(s.rig_position_m) != tuple(
                    self.rig.speakers_m[k]):
                problems.append(f"speakers[{k}].rig_position_m: {list(s.rig_position_m)} "
                                f"differs from rig.speakers_m[{k}] "
                                f"{list(self.rig.speakers_m[k])}; write the same position")
        if len(self.rig.speakers_m) != len(self.speakers):
            problems.append(f"rig.speakers_m: {len(self.rig.speakers_m)} positions for "
                            f"{len(self.speakers)} speakers; write one per speaker")
        if self.rig.reference_mark_m is None:
            problems.append("rig.reference_mark_m: missing; a capture takes the 'refmic' image, "
                            "so write the rig point touched to the reference microphone, e.g. "
                            "reference_mark_m = [-0.09, -0.06, 0.0]")
        roles = [c.role for c in self.columns]
        if roles.count("reference") != 1:
            problems.append(f"columns: {roles.count('reference')} columns have role "
                            "'reference'; write role = 'reference' on exactly the one that "
                            "records the reference microphone")
        for j, c in enumerate(self.columns):
            if c.role == "mic" and c.mic_id is None:
                problems.append(f"columns[{j}].mic_id: missing for a 'mic' column; write the "
                                "microphone's id, e.g. mic_id = 0")
        period = self._burst_layout().period_problem(self.sample_rate_hz, "burst")
        if period is not None:
            problems.append(period)
        return problems

    def _burst_layout(self) -> BurstLayout:
        """What each recording of this capture holds (the description's burst)."""
        return BurstLayout(silence_before_samples=self.burst.pre_samples,
                           mls_order=self.burst.mls_order, periods=self.burst.periods,
                           silence_after_samples=self.burst.post_samples)

    def description(self, image_sizes: dict[str, tuple[int, int]]) -> RigArrayDescription:
        """What calibration knows of a session captured with this configuration.

        Args:
            image_sizes: (width, height) of the cameras' images (a capture configuration names
                the cameras' devices, not their image sizes; the session's images do). A
                camera other than camera 0 without images is left out: there is nothing of it
                to calibrate.

        Raises:
            DescriptionError: camera 0 (the calibration's frame) has no image size.
        """
        groups: dict[str, list[tuple[int, int]]] = {}
        for j, c in enumerate(self.columns):
            if c.role == "mic":
                groups.setdefault(c.board, []).append((j, int(c.mic_id or 0)))
        reference_column = [c.role for c in self.columns].index("reference")
        frame = self.cameras[0].name
        if frame not in image_sizes:
            raise DescriptionError(f"no image of camera {frame}, the calibration's frame: its "
                                   "image size is unknown; capture the poses with it")
        return RigArrayDescription(
            sample_rate_hz=self.sample_rate_hz,
            rig=self.rig,
            channels=tuple(ChannelGroup(
                group=board, columns=tuple(j for j, _ in entries),
                mic_ids=tuple(m for _, m in entries),
                volts_per_unit=tuple(self.columns[j].volts_per_code for j, _ in entries))
                for board, entries in groups.items()),
            reference=ReferenceMicrophone(
                group=self.reference.board, reference_recordings_column=reference_column,
                pose_recordings_column=reference_column,
                distance_from_speaker_m=self.reference.distance_from_speaker_m),
            burst=self._burst_layout(),
            cameras=tuple(CameraDescription(name=c.name, width=image_sizes[c.name][0],
                                            height=image_sizes[c.name][1])
                          for c in self.cameras if c.name in image_sizes),
        )

    @classmethod
    def of_session(cls, capture: dict[str, Any], session: Path | str) -> CaptureConfig:
        """The capture configuration a session was recorded with (`SessionReader.capture`).

        Raises:
            SessionError: it does not validate (a format of another micam version, or an
                edited journal), with one clause per problem.
        """
        try:
            return cls.model_validate(capture)
        except ValidationError as exc:
            problems = "; ".join(describe_problems(exc, cls))
            raise SessionError(
                f"session {session}: its capture configuration is not one this version of micam "
                f"reads ({problems}); read it with the micam version that recorded it"
            ) from None

    def scan_configs(self) -> list[ScanConfig]:
        """One finite scan configuration per board (the sync group sets clock and trigger)."""
        return [
            ScanConfig(inputs=b.inputs, outputs=b.outputs, sample_rate_hz=self.sample_rate_hz,
                       samples_per_channel=self.burst.n_samples)
            for b in self.boards
        ]
