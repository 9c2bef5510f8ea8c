"""Faults the emulated boards can inject, each with the outcome the driver must produce."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from daq.usb._protocol import CommandCode

FaultKind = Literal["unplug", "fifo_overflow", "missing_trigger", "stall", "corrupt_reply"]


@dataclass(frozen=True)
class Fault:
    """One fault on one emulated board.

    Kinds and what the driver must report (always naming the board):
        "unplug": the board leaves the bus once it has streamed `at_sample` samples of a scan
            -> DeviceDisconnectedError with the sample index.
        "fifo_overflow": the board streams `at_sample` samples, then reports an input FIFO
            overflow on the message endpoint and stops -> OverrunError.
        "missing_trigger": the board never sees a trigger (software or external) ->
            TriggerTimeoutError.
        "stall": the input stream endpoint halts after `at_sample` samples ->
            StalledEndpointError with the sample index.
        "corrupt_reply": the first reply to `command` comes back one byte short ->
            ProtocolError (by default the register read-back of `configure`).
    Faults strike once (the unplugged board stays away; a missing trigger stays missing).
    """

    kind: FaultKind
    serial: str
    at_sample: int = 0
    command: CommandCode = CommandCode.R_MULTI_WORD_LB
