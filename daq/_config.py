"""The scan configuration of one board, validated against the board's capabilities."""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, ConfigDict, Field, field_validator

from ._errors import ConfigurationError
from ._models import BoardModel


class ClockSource(StrEnum):
    """Where the sample clock comes from: the board's own time base, or the shared clock line."""

    INTERNAL = "internal"
    EXTERNAL = "external"


class TriggerSource(StrEnum):
    """What starts the scan: a software start command, or an edge on the shared trigger line."""

    SOFTWARE = "software"
    EXTERNAL = "external"


class InputChannel(BaseModel):
    """One analog input: its channel number on the board and its bipolar full-scale range."""

    model_config = ConfigDict(frozen=True, extra="forbid")  # a typo in a config: an error

    channel: int = Field(ge=0)
    range_v: float = Field(default=10.0, gt=0)


class OutputChannel(BaseModel):
    """One analog output: its channel number on the board and its bipolar full-scale range."""

    model_config = ConfigDict(frozen=True, extra="forbid")  # a typo in a config: an error

    channel: int = Field(ge=0)
    range_v: float = Field(default=10.0, gt=0)


class ScanConfig(BaseModel):
    """What one board is asked to do during a scan.

    Inputs and outputs run on the same sample clock (`sample_rate_hz`, samples per second per
    channel). `samples_per_channel` makes a finite scan of that many samples; None scans until
    `stop`. The output waveform itself is handed to `Board.write` as raw codes; it plays once
    from the trigger, after which the outputs hold mid-scale (0 V).
    """

    model_config = ConfigDict(frozen=True)

    inputs: tuple[InputChannel, ...]
    outputs: tuple[OutputChannel, ...] = ()
    sample_rate_hz: float = Field(gt=0)
    clock: ClockSource = ClockSource.INTERNAL
    trigger: TriggerSource = TriggerSource.SOFTWARE
    samples_per_channel: int | None = Field(default=None, gt=0)

    @field_validator("inputs")
    @classmethod
    def _inputs_unique(cls, v: tuple[InputChannel, ...]) -> tuple[InputChannel, ...]:
        if not v:
            raise ValueError("a scan needs at least one input channel")
        chans = [c.channel for c in v]
        if len(set(chans)) != len(chans):
            raise ValueError(f"input channels listed twice: {chans}")
        return v

    @field_validator("outputs")
    @classmethod
    def _outputs_unique(cls, v: tuple[OutputChannel, ...]) -> tuple[OutputChannel, ...]:
        chans = [c.channel for c in v]
        if len(set(chans)) != len(chans):
            raise ValueError(f"output channels listed twice: {chans}")
        return v

    def check_against(self, model: BoardModel, serial: str = "?") -> None:
        """Raise ConfigurationError, naming the board, if `model` cannot carry out this scan."""
        where = f"{model.name} (serial {serial})"
        if self.sample_rate_hz > model.max_input_rate_hz:
            raise ConfigurationError(
                f"{where}: sample rate {self.sample_rate_hz:.0f} S/s is above the board's "
                f"maximum of {model.max_input_rate_hz:.0f} S/s per channel; lower the rate or "
                "use a faster variant"
            )
        for ch in self.inputs:
            if ch.channel >= model.n_inputs:
                raise ConfigurationError(
                    f"{where}: input channel {ch.channel} does not exist; the board has "
                    f"inputs 0..{model.n_inputs - 1}"
                )
            if ch.range_v not in model.input_ranges_v:
                raise ConfigurationError(
                    f"{where}: input range ±{ch.range_v} V is not offered; choose one of "
                    f"{', '.join(f'±{r} V' for r in model.input_ranges_v)}"
                )
        if self.outputs and not model.has_outputs:
            raise ConfigurationError(
                f"{where}: this board has no analog outputs; drive the speakers from a board "
                "with outputs (a DT9836-x-2 or -4)"
            )
        for out in self.outputs:
            if out.channel >= model.n_outputs:
                raise ConfigurationError(
                    f"{where}: output channel {out.channel} does not exist; the board has "
                    f"outputs 0..{model.n_outputs - 1}"
                )
            if out.range_v != model.output_range_v:
                raise ConfigurationError(
                    f"{where}: output range ±{out.range_v} V is not offered; the outputs are "
                    f"±{model.output_range_v} V"
                )
        if self.outputs and self.sample_rate_hz > model.max_output_rate_hz:
            raise ConfigurationError(
                f"{where}: output rate {self.sample_rate_hz:.0f} S/s is above the maximum of "
                f"{model.max_output_rate_hz:.0f} S/s"
            )
