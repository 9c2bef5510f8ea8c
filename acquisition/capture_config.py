"""The capture configuration: what hardware records what, frozen into every session's manifest.

It is the contract between acquisition and calibration: which column of a recording is which
microphone (or the reference microphone), the volts per code of each column, which output
drives which speaker, the burst, the rig and the cameras. Every model refuses unknown keys
(ConfigModel), so a misspelt key of a hand-written `[hardware.capture]` is an error.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, ValidationError, model_validator

from daq import CODE_FULL_SCALE, InputChannel, OutputChannel, ScanConfig

from .config_model import ConfigModel, describe_problems
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
    """The MLS burst each speaker plays: `pre_samples` of silence, one period of an MLS of
    `mls_order` at `amplitude_v` volts, then `post_samples` of recording while it dies away."""

    mls_order: int = Field(default=14, ge=4, le=20)
    amplitude_v: float = Field(default=1.0, gt=0, le=10)
    pre_samples: int = Field(default=512, ge=0)
    post_samples: int = Field(default=2048, ge=0)

    @property
    def n_samples(self) -> int:
        """Length of one recording, samples per channel."""
        return self.pre_samples + 2**self.mls_order - 1 + self.post_samples


class RigEntry(ConfigModel):
    """The calibration rig (see sim.geometry.Rig for the frame) and how well it is known.

    The tolerances are priors of the calibration, not corrections: it fits each speaker's
    position on the rig and the print's scale, held to the stated values with these
    standard deviations.
    """

    corners_x: int
    corners_y: int
    square_m: float
    speakers_m: tuple[tuple[float, float, float], ...]
    reference_mark_m: tuple[float, float, float]
    speaker_tolerance_m: float = Field(
        default=3e-4, ge=0, le=0.01,
        description="build tolerance: standard deviation, per axis in the board plane, of each "
                    "speaker's position about its stated one (m)")
    acoustic_centre_m: float = Field(
        default=0.0, ge=-0.02, le=0.02,
        description="expected offset of each speaker's acoustic centre from its stated "
                    "position along the board normal, + out of the printed face (m)")
    acoustic_centre_std_m: float = Field(
        default=5e-3, ge=0, le=0.05,
        description="standard deviation of that offset, per speaker (m)")
    print_scale_std: float = Field(
        default=2e-3, ge=0, le=0.05,
        description="relative standard deviation of the printed pattern's scale about the "
                    "stated square size (0.002: within about 0.2 %)")
    speaker_diameter_m: float | None = Field(
        default=None, gt=0, le=0.5,
        description="the speakers' diameter: their off-axis roll-off is then taken out of "
                    "the microphones' estimated gains")


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
        return self

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
