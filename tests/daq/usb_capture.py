"""Captures of emulated USB traffic, written as usbmon and USBPcap would, for the trace tests.

`RecordingBackend` wraps the emulated bus's pyusb backend and records every transfer with its
submission and completion (time, bus, address, endpoint, setup, data, outcome), as a host
controller driver sees it. The writers turn the recording into capture files, building every
byte here with `struct` from the documented layouts (the Linux kernel's usbmon.rst
`struct usbmon_packet`; desowin.org/usbpcap/captureformat.html; the pcap and pcapng file
formats), independently of the reader under test.
"""

from __future__ import annotations

import array
import errno
import itertools
import struct
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable
from typing import Any

import usb.core

from sim.usb import EmulatedBackend, EmulatedBus

_EINPROGRESS = -errno.EINPROGRESS


@dataclass(frozen=True)
class Recorded:
    """One transfer as the host saw it."""

    urb: int
    t_submit: float
    t_complete: float
    bus: int
    address: int
    kind: str  # "ctrl" or "bulk"
    endpoint: int  # with the direction bit; control: 0x00 / 0x80
    setup: bytes | None
    out: bytes  # the data sent (OUT)
    requested: int  # bytes asked for (IN) or sent (OUT)
    received: bytes  # the data received (IN)
    errno: int  # 0 if it completed, else the errno of pyusb's error


class RecordingBackend(EmulatedBackend):
    """The emulated bus's backend, recording every control and bulk transfer (clear_halt as
    the CLEAR_FEATURE(ENDPOINT_HALT) request it is on the wire)."""

    def __init__(self, bus: EmulatedBus) -> None:
        super().__init__(bus)
        self.transfers: list[Recorded] = []
        self._lock = threading.Lock()
        self._ids = itertools.count(0xFFFF_8800_0000_0000, 0x100)

    def _record(self, handle: Any, kind: str, endpoint: int, setup: bytes | None, out: bytes,
                requested: int, call: Callable[[], bytes]) -> bytes:
        bus, address = handle.board.descriptor.bus, handle.board.descriptor.address
        t0 = time.time()
        received, err = b"", 0
        try:
            received = call()
            return received
        except usb.core.USBError as e:
            err = e.errno or errno.EIO
            raise
        finally:
            with self._lock:
                self.transfers.append(Recorded(next(self._ids), t0, time.time(), bus, address,
                                               kind, endpoint, setup, out, requested, received,
                                               err))

    def ctrl_transfer(self, handle: Any, bmRequestType: int, bRequest: int, wValue: int,
                      wIndex: int, data: array.array, timeout: int) -> int:
        def call() -> bytes:
            EmulatedBackend.ctrl_transfer(self, handle, bmRequestType, bRequest, wValue, wIndex,
                                          data, timeout)
            return b""
        setup = struct.pack("<BBHHH", bmRequestType, bRequest, wValue, wIndex, len(data))
        self._record(handle, "ctrl", bmRequestType & 0x80, setup, data.tobytes(), len(data),
                     call)
        return len(data)

    def bulk_write(self, handle: Any, ep: int, intf: int, data: array.array,
                   timeout: int) -> int:
        def call() -> bytes:
            EmulatedBackend.bulk_write(self, handle, ep, intf, data, timeout)
            return b""
        self._record(handle, "bulk", ep, None, data.tobytes(), len(data), call)
        return len(data)

    def bulk_read(self, handle: Any, ep: int, intf: int, buff: array.array,
                  timeout: int) -> int:
        def call() -> bytes:
            n = EmulatedBackend.bulk_read(self, handle, ep, intf, buff, timeout)
            return buff[:n].tobytes()
        return len(self._record(handle, "bulk", ep, None, b"", len(buff), call))

    def clear_halt(self, handle: Any, ep: int) -> None:
        def call() -> bytes:
            EmulatedBackend.clear_halt(self, handle, ep)
            return b""
        setup = struct.pack("<BBHHH", 0x02, 0x01, 0x0000, ep, 0)
        self._record(handle, "ctrl", 0x00, setup, b"", 0, call)


# -- usbmon (Documentation/usb/usbmon.rst: struct usbmon_packet) ------------------------------


def usbmon_header(urb: int, kind: str, xfer: int, epnum: int, devnum: int, busnum: int,
                  setup: bytes | None, has_data: bool, ts: float, status: int, length: int,
                  len_cap: int, mmapped: bool, big: bool = False) -> bytes:
    """The 48-byte (LINKTYPE_USB_LINUX) or 64-byte (..._MMAPPED) header, field by field."""
    order = ">" if big else "<"
    sec = int(ts)
    head = struct.pack(order + "QBBBBHbbqiiII8s", urb, ord(kind), xfer, epnum, devnum, busnum,
                       0 if setup is not None else ord("-"), 0 if has_data else ord("<"),
                       sec, round((ts - sec) * 1e6), status, length, len_cap,
                       setup if setup is not None else bytes(8))
    return head + (struct.pack(order + "iiII", 0, 0, 0, 0) if mmapped else b"")


def usbmon_records(recorded: list[Recorded], mmapped: bool,
                   big: bool = False) -> list[tuple[float, bytes]]:
    """Every transfer as its 'S' and 'C' events, in time order."""
    events = []
    for r in recorded:
        xfer = 2 if r.kind == "ctrl" else 3
        is_in = bool(r.endpoint & 0x80)
        out = b"" if is_in else r.out
        events.append((r.t_submit, usbmon_header(
            r.urb, "S", xfer, r.endpoint, r.address, r.bus, r.setup, bool(out), r.t_submit,
            _EINPROGRESS, r.requested, len(out), mmapped, big) + out))
        status = 0 if r.errno == 0 else (-errno.ENOENT if r.errno == errno.ETIMEDOUT
                                         else -r.errno)  # libusb cancels on a timeout
        got = r.received if is_in else b""
        length = len(r.received) if is_in else (r.requested if r.errno == 0 else 0)
        events.append((r.t_complete, usbmon_header(
            r.urb, "C", xfer, r.endpoint, r.address, r.bus, None, bool(got), r.t_complete,
            status, length, len(got), mmapped, big) + got))
    return sorted(events, key=lambda e: e[0])


# -- USBPcap (desowin.org/usbpcap/captureformat.html) -----------------------------------------

_USBD = {0: 0x00000000, errno.ETIMEDOUT: 0xC0010000, errno.EPIPE: 0xC0000004,
         errno.ENODEV: 0xC0007000}


def usbpcap_header(irp: int, status: int, function: int, completion: bool, bus: int,
                   device: int, endpoint: int, transfer: int, data_length: int,
                   stage: int | None = None) -> bytes:
    """USBPCAP_BUFFER_PACKET_HEADER (27 bytes, packed, little-endian) and, for control
    transfers, the stage byte (headerLen 28)."""
    header_len = 27 + (stage is not None)
    head = struct.pack("<HQIHBHHBBI", header_len, irp, status, function, int(completion), bus,
                       device, endpoint, transfer, data_length)
    return head + (bytes([stage]) if stage is not None else b"")


def usbpcap_records(recorded: list[Recorded]) -> list[tuple[float, bytes]]:
    events = []
    for r in recorded:
        status = _USBD.get(r.errno, 0xC0000011)
        is_in = bool(r.endpoint & 0x80)
        if r.kind == "ctrl":
            assert r.setup is not None
            events.append((r.t_submit, usbpcap_header(r.urb, 0, 0x0008, False, r.bus, r.address,
                                                      0x00, 2, 8, stage=0) + r.setup))
            if r.out:
                events.append((r.t_submit, usbpcap_header(r.urb, 0, 0x0008, False, r.bus,
                                                          r.address, 0x00, 2, len(r.out),
                                                          stage=1) + r.out))
            events.append((r.t_complete, usbpcap_header(
                r.urb, status, 0x0008, True, r.bus, r.address, r.endpoint, 2,
                len(r.received), stage=3) + r.received))
            continue
        out = b"" if is_in else r.out
        events.append((r.t_submit, usbpcap_header(r.urb, 0, 0x0009, False, r.bus, r.address,
                                                  r.endpoint, 3, len(out)) + out))
        got = r.received if is_in else b""
        events.append((r.t_complete, usbpcap_header(r.urb, status, 0x0009, True, r.bus,
                                                    r.address, r.endpoint, 3, len(got)) + got))
    return sorted(events, key=lambda e: e[0])


# -- the file formats ---------------------------------------------------------------------


def write_pcap(path: Path, linktype: int, records: list[tuple[float, bytes]],
               big: bool = False) -> Path:
    """Classic pcap: the 24-byte file header, then per record a 16-byte header and the data."""
    order = ">" if big else "<"
    out = [struct.pack(order + "IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, linktype)]
    for ts, data in records:
        sec = int(ts)
        out.append(struct.pack(order + "IIII", sec, round((ts - sec) * 1e6), len(data),
                               len(data)) + data)
    path.write_bytes(b"".join(out))
    return path


def write_pcapng(path: Path, linktype: int, records: list[tuple[float, bytes]],
                 big: bool = False) -> Path:
    """pcapng: a section header, one interface (microsecond stamps), enhanced packet blocks."""
    o = ">" if big else "<"
    out = [struct.pack(o + "IIIHHqI", 0x0A0D0D0A, 28, 0x1A2B3C4D, 1, 0, -1, 28),
           struct.pack(o + "IIHHII", 1, 20, linktype, 0, 262144, 20)]
    for ts, data in records:
        stamp = round(ts * 1e6)
        pad = -len(data) % 4
        total = 32 + len(data) + pad
        out.append(struct.pack(o + "IIIIIII", 6, total, 0, stamp >> 32, stamp & 0xFFFFFFFF,
                               len(data), len(data)) + data + bytes(pad)
                   + struct.pack(o + "I", total))
    path.write_bytes(b"".join(out))
    return path
