"""Errors of the USB driver, on top of the driver-layer errors of `daq`.

Like every daq error, each message names the board (model and serial once known, else its USB
location) and says what to do.
"""

from __future__ import annotations

from daq import DaqError


class UsbTransferError(DaqError):
    """A USB transfer failed for a reason other than unplugging (see the subclasses)."""


class TransferTimeoutError(UsbTransferError):
    """A transfer did not complete within its timeout (the board did not answer)."""


class StalledEndpointError(UsbTransferError):
    """The board halted (stalled) an endpoint: it refused the transfer."""


class ProtocolError(DaqError):
    """The board answered something the wire protocol does not allow (a corrupt reply)."""


class FirmwareError(DaqError):
    """The firmware images are missing or unreadable, or the board did not re-enumerate."""


def with_context(error: DaqError, context: str) -> DaqError:
    """A copy of `error` (same class) whose message ends with `context`, e.g. a sample index."""
    clone = type(error)(f"{error}; {context}")
    clone.__cause__ = error
    return clone
