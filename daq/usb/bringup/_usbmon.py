"""Linux usbmon records (link types 189 and 220) paired into transfers.

The header is the kernel's `struct usbmon_packet` (Documentation/usb/usbmon.rst, "Raw binary
format and API"; libpcap's `pcap/usb.h`), in the byte order of the capture file (tcpdump.org's
link-type list: LINKTYPE_USB_LINUX, LINKTYPE_USB_LINUX_MMAPPED):

    offset  field
     0  u64 id           URB id: a submission and its completion share it
     8  u8  type         'S' submission, 'C' completion, 'E' submission error
     9  u8  xfer_type    0 isochronous, 1 interrupt, 2 control, 3 bulk
    10  u8  epnum        endpoint number; bit 7 set for IN
    11  u8  devnum       device address
    12  u16 busnum
    14  s8  flag_setup   0 when `setup` holds the setup packet (control submissions)
    15  s8  flag_data    0 when data follows the header
    16  s64 ts_sec;  24 s32 ts_usec
    28  s32 status       0, or a negative errno (-EINPROGRESS in a submission)
    32  u32 length       bytes submitted (S) or transferred (C)
    36  u32 len_cap      bytes of data captured after the header
    40  u8  setup[8]     (isochronous: error_count, numdesc)
    48  s32 interval; 52 s32 start_frame; 56 u32 xfer_flags; 60 u32 ndesc   (link type 220)

After the 64-byte header come `ndesc` isochronous descriptors of 16 bytes, then the data.
An OUT transfer's data is in its submission, an IN transfer's in its completion. A transfer
becomes a `Transfer` at its completion; submissions the capture never completes come out at
the end as INCOMPLETE (at most MAX_PENDING are held, so memory stays bounded).
"""

from __future__ import annotations

import errno
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

from ._errors import TraceError
from ._files import LINKTYPE_USB_LINUX_MMAPPED, Record
from ._transfer import DATA_BYTES, Kind, Setup, Status, Transfer, device_key, incomplete

MAX_PENDING = 65_536
"""Submissions awaiting their completion; beyond it the oldest is given up as INCOMPLETE."""

_HEADER = "QBBBBHbbqiiII8s"
_EXTENSION = "iiII"
_KINDS: tuple[Kind, ...] = ("iso", "intr", "ctrl", "bulk")
_STATUS = {0: Status.OK, -errno.ENOENT: Status.CANCELLED, -errno.ECONNRESET: Status.CANCELLED,
           -errno.EPIPE: Status.STALL, -errno.ENODEV: Status.GONE,
           -errno.ESHUTDOWN: Status.GONE}
_ISO_DESCRIPTOR = 16


@dataclass(frozen=True)
class _Event:
    ts: float
    urb: int
    type: str
    kind: Kind
    endpoint: int
    device: str
    setup: Setup | None
    status: int
    length: int
    data: bytes
    index: int


def transfers(path: Path, records: Iterable[Record], linktype: int,
              big_endian: bool) -> Iterator[Transfer]:
    """The transfers of a usbmon capture, in the order they completed."""
    fmt = (">" if big_endian else "<") + _HEADER
    if linktype == LINKTYPE_USB_LINUX_MMAPPED:
        fmt += _EXTENSION
    size = struct.calcsize(fmt)
    pending: dict[tuple[str, int], _Event] = {}
    t0: float | None = None
    for record in records:
        t0 = record.ts if t0 is None else t0
        event = _parse(path, record, fmt, size)
        key = (event.device, event.urb)
        if event.type == "S":
            if len(pending) >= MAX_PENDING:
                oldest = next(iter(pending))
                yield _abandoned(pending.pop(oldest), t0)
            pending[key] = event
            continue
        yield _transfer(pending.pop(key, None), event, t0)
    for submission in pending.values():
        yield _abandoned(submission, t0 if t0 is not None else 0.0)


def _parse(path: Path, record: Record, fmt: str, size: int) -> _Event:
    raw = record.data
    if len(raw) < size:
        raise TraceError(f"{path}: record {record.index} has {len(raw)} bytes, fewer than the "
                         f"{size}-byte usbmon header: the file is damaged")
    fields = struct.unpack_from(fmt, raw)
    urb, kind, xfer, epnum, devnum, busnum, flag_setup = fields[:7]
    status, length, len_cap, setup = fields[10:14]
    if kind not in b"SCE" or xfer >= len(_KINDS):
        raise TraceError(f"{path}: record {record.index} is not a usbmon event (type 0x{kind:02x}"
                         f", transfer type {xfer}): the file is damaged")
    ndesc = fields[17] if len(fields) > 14 else 0  # the 64-byte header's last field
    offset = size + (_ISO_DESCRIPTOR * ndesc if xfer == 0 else 0)
    data = raw[offset: offset + min(len_cap, DATA_BYTES)]
    return _Event(record.ts, urb, chr(kind), _KINDS[xfer], epnum, device_key(busnum, devnum),
                  Setup.parse(setup) if xfer == 2 and flag_setup == 0 and kind == ord("S")
                  else None, status, length, data, record.index)


def _transfer(submitted: _Event | None, completed: _Event, t0: float) -> Transfer:
    is_in = bool(completed.endpoint & 0x80)
    if submitted is None:  # the capture began while this transfer was under way
        length, data, setup = completed.length, completed.data if is_in else b"", None
    else:
        length = completed.length if is_in else submitted.length
        data = completed.data if is_in else submitted.data
        setup = submitted.setup
    status = _STATUS.get(completed.status, Status.ERROR)
    detail = "" if status is Status.OK else errno.errorcode.get(-completed.status,
                                                                str(completed.status))
    return Transfer(completed.ts - t0, completed.device, completed.kind, completed.endpoint,
                    setup, length, data, status, detail, completed.index)


def _abandoned(s: _Event, t0: float) -> Transfer:
    return incomplete(s.ts - t0, s.device, s.kind, s.endpoint, s.setup, s.length, s.data,
                      s.index)
