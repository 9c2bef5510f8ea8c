"""One USB transfer as a capture or micam's trace saw it, whatever the file's format.

usbmon and USBPcap record a transfer as a submission and a completion; micam's trace records
it once, when it completed. All three become a `Transfer`: who (the device), what (control
setup or endpoint, direction), how much (`length`, the bytes actually transferred), the first
bytes of the data and how it ended (`status`, one vocabulary for every source).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Literal

DATA_BYTES = 64
"""Bytes of data kept per transfer: one command packet or reply, the first frames of a
stream transfer. micam's trace keeps as many (`TransferTrace.max_data_bytes`), so a capture
and a trace of the same traffic decode alike, and memory stays bounded however long the
capture."""

Kind = Literal["ctrl", "bulk", "intr", "iso", "other"]


class Status(StrEnum):
    """How a transfer ended, in words shared by usbmon, USBPcap and micam's trace."""

    OK = "ok"
    CANCELLED = "cancelled"
    """Unlinked before it completed: a timeout of libusb or the vendor's driver, or the
    program closing the device (usbmon -ENOENT/-ECONNRESET, USBD_STATUS_CANCELED, and
    micam's "timed out", which libusb implements by cancelling the transfer)."""
    STALL = "stall"
    GONE = "gone"
    """The device left the bus."""
    INCOMPLETE = "incomplete"
    """Submitted, but the capture holds no completion (it ended first)."""
    ERROR = "error"


@dataclass(frozen=True)
class Setup:
    """The 8-byte setup packet of a control transfer (USB 2.0, 9.3; little-endian words)."""

    request_type: int
    request: int
    value: int
    index: int
    length: int

    @classmethod
    def parse(cls, packet: bytes) -> Setup:
        return cls(packet[0], packet[1], int.from_bytes(packet[2:4], "little"),
                   int.from_bytes(packet[4:6], "little"), int.from_bytes(packet[6:8], "little"))


@dataclass(frozen=True)
class Transfer:
    """One completed (or abandoned) transfer.

    Attributes:
        t: seconds since the first record of the file.
        device: "BUS:ADDRESS" (e.g. "1:3"), or micam's device name for a trace written
            before traces carried the address.
        kind: the transfer type.
        endpoint: endpoint address with the direction bit (0x81 is IN 1); 0x00 or 0x80 for
            control transfers (the direction of their data stage).
        setup: the setup packet of a control transfer, if the file holds it.
        length: bytes transferred (for an IN transfer, what the device sent).
        data: the first `DATA_BYTES` bytes of the data, as far as the file captured them.
        status: how it ended.
        detail: the source's own word for a status other than ok (an errno, a USBD_STATUS).
        source: where in the file: record number (pcap) or line number (micam's trace), 0 up.
        name: micam's name of the device ("DT9836-12-2 serial 3"), in micam's traces only.
    """

    t: float
    device: str
    kind: Kind
    endpoint: int
    setup: Setup | None
    length: int
    data: bytes
    status: Status
    detail: str
    source: int
    name: str | None = None

    @property
    def is_in(self) -> bool:
        return bool(self.endpoint & 0x80)


def device_key(bus: int, address: int) -> str:
    """The name of a device in every decoded file: "BUS:ADDRESS", as `--device` takes it."""
    return f"{bus}:{address}"


def incomplete(t: float, device: str, kind: Kind, endpoint: int, setup: Setup | None,
               submitted: int, data: bytes, source: int) -> Transfer:
    """A submission the capture holds no completion of: an OUT transfer with what it
    submitted, an IN transfer with nothing received."""
    is_in = bool(endpoint & 0x80)
    return Transfer(t, device, kind, endpoint, setup, 0 if is_in else submitted,
                    b"" if is_in else data, Status.INCOMPLETE, "no completion", source)
