"""Errors of the bring-up kit: files it cannot read, and a probe step that would write."""

from __future__ import annotations

from daq import DaqError


class TraceError(DaqError):
    """A capture or trace file that cannot be read: the message names the file, the record
    (or line) and what is wrong with it, and says what to do. The command line reports it as
    a bad input (exit 2)."""


class WriteRefusedError(DaqError):
    """The read-only probe was asked to send a command that changes a board's state."""
