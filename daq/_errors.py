"""Errors raised by the driver layer.

Every error names the board (model and serial) it concerns and, where it applies, the sample
index at which it happened, so that an operator can tell which cable or which board to check.
"""

from __future__ import annotations


class DaqError(RuntimeError):
    """Base class of every driver-layer error."""


class ConfigurationError(DaqError, ValueError):
    """A scan configuration that the board cannot carry out (rate, channel, range, outputs)."""


class BoardStateError(DaqError):
    """A call made in the wrong order (for example `start` before `configure`)."""


class OverrunError(DaqError):
    """The board's input FIFO overflowed or a block was lost: the data is no longer contiguous."""


class UnderrunError(DaqError):
    """The board's output FIFO ran empty while an output waveform was still playing."""


class TriggerTimeoutError(DaqError):
    """An armed board saw no trigger (or no external clock) within the allowed time."""


class DeviceDisconnectedError(DaqError):
    """The board disappeared from the bus (unplugged, powered off, or reset)."""


class SyncError(DaqError):
    """Boards of one sync group disagree on the sample index or sample count of a block."""
