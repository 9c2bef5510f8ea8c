"""Every guess the driver makes about what no public source states, in this one module.

Public (see `_ids`, `_registers`, `_protocol`): the DT9836 USB ids, endpoints, command packets
and FPGA register map. *Not* public, and therefore guessed here:

- the whole DT9816: its running product id (guessed 0x1698, the byte-swapped loader id as for
  the DT9836 and DT9837), its version register values, and that it speaks the DT9836 command
  set with the DT9836 register map (six input channels, one ±10 V range, no outputs);
- the DT9836 scan set-up: SAMPLES_PER_TRIG holds the scan length (0 = continuous), the sample
  clock period is `36 MHz / rate` (not `- 1`), inputs single-ended, converters in two's
  complement (MISC_CTRLS) so that stream codes are signed;
- the start sequence: arm with IO_OP_CONTROL (INPUT_SCAN_ARM, OUTPUT_ARM) then START_SUBSYSTEM
  (DA before AD, ExtTrig = 1 for a positive external edge as on the DT9837, else 0); release
  a software-triggered scan with IO_OP_CONTROL soft-trigger bits; stop with STOP_SUBSYSTEM and
  INPUT_SCAN_STOP; the DAC stream is written to endpoint 0x06 before the output is armed;
- the stream formats: one frame per sample clock edge, the enabled channels in ascending
  order, each sample a little-endian signed 16-bit code, on 0x82 (inputs) and 0x06 (outputs).

How to correct it: capture Data Translation's software doing a scan (usbmon or USBPcap) and
micam doing the same (a capture or a `TransferTrace`); `micam daq trace diff` names the entry
below (`Guess`) each difference contradicts; change the values here and pin them in
tests/daq/test_usb_guesses_pinned.py (docs/usb-protocol.md, "Correcting the guesses"). The
emulated device (sim.usb) imports the same guesses, so its tests keep passing and the emulator
follows automatically.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from daq import ConfigurationError

from ._protocol import Command, StartSubsystem, StopSubsystem, Subsystem, WriteWord
from ._registers import (
    BASE_CLOCK_HZ,
    DAC_RELEASED,
    InputControl,
    IoOp,
    Misc,
    OutputControl,
    Reg,
)


class Guess(StrEnum):
    """The guesses of this module by name, each value the module attribute that holds it.

    `micam daq trace diff` names these when a capture contradicts one (a test keeps every
    value resolvable here, so a renamed guess cannot leave the diff naming a stale one).
    """

    DT9816_RUNNING_PID = "DT9816_RUNNING_PID"
    DT9816_VERSION_IDS = "DT9816_VERSION_IDS"
    EXT_TRIG_POSITIVE_EDGE = "EXT_TRIG_POSITIVE_EDGE"
    STREAM_DTYPE = "STREAM_DTYPE"
    SCAN_REGISTERS = "ScanSettings.registers"
    CLOCK_PERIOD = "clock_period"
    ARM_COMMANDS = "arm_commands"
    SOFTWARE_TRIGGER_COMMANDS = "software_trigger_commands"
    STOP_COMMANDS = "stop_commands"


DT9816_RUNNING_PID = 0x1698
"""Guess: the DT9816 after firmware download (byte-swapped loader id). Check with lsusb."""

DT9816_VERSION_IDS: dict[int, str] = {0x0816: "DT9816", 0x4816: "DT9816-A"}
"""Guess: VERSION_ID register values of the DT9816 variants (placeholders until a capture)."""

EXT_TRIG_POSITIVE_EDGE = 0x0001
"""Guess: START_SUBSYSTEM ExtTrig flags for a rising external trigger (the DT9837 value)."""

STREAM_DTYPE = np.dtype("<i2")
"""Guess: each stream sample is a little-endian signed 16-bit code."""

MAX_CLOCK_PERIOD = 0xFFFF_FFFF
"""The sample clock period is a 32-bit register pair (lo/hi)."""


@dataclass(frozen=True)
class ScanSettings:
    """What the board is told about a scan, as register contents.

    Attributes:
        inputs: enabled input channel numbers (ascending: the order of the stream).
        two_volt_range: True selects the ±2 V input range (one bit for the whole board).
        outputs: enabled output channel numbers (ascending).
        external_clock: sample on the shared external clock instead of the internal one.
        external_trigger: start on the shared external trigger instead of a software start.
        samples: scan length in samples per channel; 0 scans until stopped.
        clock_period: internal sample clock divider, in ticks of the 36 MHz time base.
    """

    inputs: tuple[int, ...]
    two_volt_range: bool
    outputs: tuple[int, ...]
    external_clock: bool
    external_trigger: bool
    samples: int
    clock_period: int

    def registers(self) -> tuple[tuple[int, int], ...]:
        """The (address, value) writes that set the board up for this scan."""
        inp = InputControl.ADC_SINGLE_ENDED
        if self.two_volt_range:
            inp |= InputControl.ADC_2V_RANGE
        if self.external_clock:
            inp |= InputControl.EXT_SAMPLE_CLK
        if self.external_trigger:
            inp |= InputControl.EXT_TRIGGER | InputControl.EXT_TRIGGER_POLARITY
        out = int(DAC_RELEASED) | _mask(self.outputs)
        if self.outputs and self.external_clock:
            out |= OutputControl.EXT_SAMPLE_CLK
        if self.outputs and self.external_trigger:
            out |= OutputControl.EXT_TRIGGER | OutputControl.EXT_TRIGGER_POLARITY
        mask = _mask(self.inputs)
        return (
            (Reg.MISC_CTRLS, int(Misc.ADC_TWOS_COMP | Misc.DAC_TWOS_COMP)),
            (Reg.INPUT_CONTROL0, int(inp)),
            (Reg.INPUT_CHAN_MASK_LO, mask & 0xFFFF),
            (Reg.INPUT_CHAN_MASK_HI, mask >> 16),
            (Reg.SAMPLES_PER_TRIG_LO, self.samples & 0xFFFF),
            (Reg.SAMPLES_PER_TRIG_HI, self.samples >> 16),
            (Reg.IN_SAMPLE_CLK_PERIOD_LO, self.clock_period & 0xFFFF),
            (Reg.IN_SAMPLE_CLK_PERIOD_HI, self.clock_period >> 16),
            (Reg.OUT_SAMPLE_CLK_PERIOD_LO, self.clock_period & 0xFFFF),
            (Reg.OUT_SAMPLE_CLK_PERIOD_HI, self.clock_period >> 16),
            (Reg.OUTPUT_CONTROL, int(out)),
        )

    @classmethod
    def from_registers(cls, read: Callable[[int], int]) -> ScanSettings:
        """Decode the settings from a register file (the emulated device's view)."""
        inp = InputControl(read(Reg.INPUT_CONTROL0))
        out = read(Reg.OUTPUT_CONTROL)
        mask = read(Reg.INPUT_CHAN_MASK_LO) | read(Reg.INPUT_CHAN_MASK_HI) << 16
        return cls(
            inputs=_channels(mask),
            two_volt_range=InputControl.ADC_2V_RANGE in inp,
            outputs=_channels(out & 0xF),
            external_clock=InputControl.EXT_SAMPLE_CLK in inp,
            external_trigger=InputControl.EXT_TRIGGER in inp,
            samples=read(Reg.SAMPLES_PER_TRIG_LO) | read(Reg.SAMPLES_PER_TRIG_HI) << 16,
            clock_period=(read(Reg.IN_SAMPLE_CLK_PERIOD_LO)
                          | read(Reg.IN_SAMPLE_CLK_PERIOD_HI) << 16),
        )

    @property
    def rate_hz(self) -> float:
        """The internal sample clock rate this period gives, in samples per second."""
        return BASE_CLOCK_HZ / self.clock_period


def clock_period(rate_hz: float, where: str) -> int:
    """The sample clock divider for `rate_hz`; ConfigurationError if the rate is not reachable.

    The boards share one clock, so an approximate rate would silently shift every time of
    flight: only rates that divide 36 MHz exactly (to 1 ppm) are accepted.
    """
    period = round(BASE_CLOCK_HZ / rate_hz)
    exact = (1 <= period <= MAX_CLOCK_PERIOD
             and abs(BASE_CLOCK_HZ / period - rate_hz) <= rate_hz * 1e-6)
    if not exact:
        lo, hi = BASE_CLOCK_HZ / (period + 1), BASE_CLOCK_HZ / max(period, 1)
        raise ConfigurationError(
            f"{where}: {rate_hz:.3f} S/s is not 36 MHz divided by a whole number; the nearest "
            f"rates are {lo:.3f} and {hi:.3f} S/s"
        )
    return period


def arm_commands(settings: ScanSettings) -> list[Command]:
    """Commands that arm a configured board (after the DAC stream is written)."""
    flags = EXT_TRIG_POSITIVE_EDGE if settings.external_trigger else 0
    io = IoOp.INPUT_SCAN_ARM | (IoOp.OUTPUT_ARM if settings.outputs else 0)
    commands: list[Command] = [WriteWord(Reg.IO_OP_CONTROL, int(io))]
    if settings.outputs:
        commands.append(StartSubsystem(Subsystem.DA, flags))
    commands.append(StartSubsystem(Subsystem.AD, flags))
    return commands


def software_trigger_commands(settings: ScanSettings) -> list[Command]:
    """Commands that release an armed, software-triggered scan (inputs and outputs at once)."""
    io = IoOp.INPUT_SOFT_TRIGGER | (IoOp.OUTPUT_SOFT_TRIGGER if settings.outputs else 0)
    return [WriteWord(Reg.IO_OP_CONTROL, int(io))]


def stop_commands(settings: ScanSettings) -> list[Command]:
    """Commands that end a scan and leave the board ready to be armed again."""
    commands: list[Command] = [StopSubsystem(Subsystem.AD)]
    if settings.outputs:
        commands.append(StopSubsystem(Subsystem.DA))
    commands.append(WriteWord(Reg.IO_OP_CONTROL, int(IoOp.INPUT_SCAN_STOP)))
    return commands


def encode_stream(codes: np.ndarray) -> bytes:
    """Frames of int16 codes (n_samples, n_channels) to stream bytes."""
    return np.ascontiguousarray(codes, dtype=STREAM_DTYPE).tobytes()


def decode_stream(data: bytes | memoryview, n_channels: int) -> np.ndarray:
    """Stream bytes (whole frames only) to int16 codes (n_samples, n_channels)."""
    return np.frombuffer(data, dtype=STREAM_DTYPE).astype(np.int16).reshape(-1, n_channels)


def _mask(channels: Sequence[int]) -> int:
    m = 0
    for c in channels:
        m |= 1 << c
    return m


def _channels(mask: int) -> tuple[int, ...]:
    return tuple(i for i in range(mask.bit_length()) if mask >> i & 1)
