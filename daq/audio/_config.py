"""How a configuration names the audio interfaces (the daemon's `[hardware.audio]`)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class AudioDeviceConfig(BaseModel):
    """One interface: the label the capture's boards use, and PortAudio's name for it."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    label: str = Field(min_length=1, max_length=64,
                       description="the serial of its [[hardware.capture.boards]] entry")
    name: str = Field(min_length=1, max_length=256,
                      description="the device's name, or a part of it that names only it, as "
                                  "`micam daq list --backend audio` shows it")
    host_api: str | None = Field(default=None, max_length=64,
                                 description="ALSA, JACK, Core Audio, WASAPI, ASIO, ...: when "
                                             "the interface appears under several")


class AudioConfig(BaseModel):
    """The interfaces of an audio-backend rig.

    Several interfaces record together only when one word clock drives them all (the first
    interface's word-clock output into every other's word-clock input, those set to external
    clock): `word_clock = true` says so. micam then keeps their sample offset fixed and fails
    a trigger whose interfaces drift apart (daq.audio._clock).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    devices: tuple[AudioDeviceConfig, ...] = Field(min_length=1, max_length=16)
    word_clock: bool = Field(
        default=False, description="true: the interfaces share one word clock (needed for more "
                                   "than one); the first is the clock master")
    block_frames: int = Field(default=0, ge=0, le=16_384,
                              description="frames per callback; 0: the host API's choice")
    latency: Literal["low", "high"] | float = Field(
        default="high", description="PortAudio's suggested latency: low, high or seconds (a "
                                    "larger buffer rides out a busy machine; the latency "
                                    "itself is measured by the reference microphone)")

    @model_validator(mode="after")
    def _consistent(self) -> AudioConfig:
        labels = [d.label for d in self.devices]
        if len(set(labels)) != len(labels):
            raise ValueError(f"devices: a label is used twice: {labels}")
        if len(self.devices) > 1 and not self.word_clock:
            raise ValueError(
                f"{len(self.devices)} interfaces need one word clock: wire the first's word "
                "clock to the others (set to external clock) and write word_clock = true, or "
                "record with one interface")
        if isinstance(self.latency, float) and not 0 < self.latency <= 1.0:
            raise ValueError(f"latency {self.latency} s must be in (0, 1]")
        return self

    def device(self, label: str) -> AudioDeviceConfig:
        for d in self.devices:
            if d.label == label:
                return d
        raise KeyError(label)
