"""Windows USBPcap records (link type 249) paired into transfers.

The header is USBPcap's `USBPCAP_BUFFER_PACKET_HEADER` (desowin.org/usbpcap/captureformat.html;
USBPcapBuffer.h), packed and little-endian:

    offset  field
     0  u16 headerLen   this header's length, the transfer-specific part included
     2  u64 irpId       the I/O request: a submission and its completion share it
    10  u32 status      USBD_STATUS, valid in completions
    14  u16 function    URB function
    16  u8  info        bit 0 (USBPCAP_INFO_PDO_TO_FDO): 1 on the way back (a completion)
    17  u16 bus         root hub
    19  u16 device      device address
    21  u8  endpoint    endpoint number; bit 7 set for IN
    22  u8  transfer    0 isochronous, 1 interrupt, 2 control, 3 bulk, 0xFE IRP information
    23  u32 dataLength  bytes of data after the header
    27  u8  stage       control transfers only: 0 setup, 1 data, 2 status, 3 complete

A control transfer comes as a setup stage (its 8 data bytes are the setup packet; older
USBPcap versions append the OUT data), an optional data stage, and, on the way back, data,
status or complete stages (Wireshark's packet-usb.c reads them the same way). A transfer
becomes a `Transfer` when its completion ends it; requests never completed come out at the end
as INCOMPLETE (at most MAX_PENDING are held).
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from ._errors import TraceError
from ._files import Record
from ._transfer import DATA_BYTES, Kind, Setup, Status, Transfer, device_key, incomplete

MAX_PENDING = 65_536
"""Requests awaiting their completion; beyond it the oldest is given up as INCOMPLETE."""

_HEADER = struct.Struct("<HQIHBHHBBI")
_CONTROL = 2
_STAGE_SETUP, _STAGE_DATA = 0, 1
_KINDS: dict[int, Kind] = {0: "iso", 1: "intr", 2: "ctrl", 3: "bulk"}
_STATUS = {0x00000000: Status.OK, 0xC0010000: Status.CANCELLED, 0xC0006000: Status.CANCELLED,
           0xC0000004: Status.STALL, 0xC0000030: Status.STALL, 0xC0007000: Status.GONE}
"""USBD_STATUS: SUCCESS, CANCELED, TIMEOUT, STALL_PID, ENDPOINT_HALTED, DEVICE_GONE."""


@dataclass
class _Request:
    ts: float
    kind: Kind
    endpoint: int
    device: str
    index: int
    setup: Setup | None = None
    out: bytes = b""
    out_length: int = 0
    received: bytearray = field(default_factory=bytearray)
    in_length: int = 0


def transfers(path: Path, records: Iterable[Record]) -> Iterator[Transfer]:
    """The transfers of a USBPcap capture, in the order they completed."""
    pending: dict[int, _Request] = {}
    t0: float | None = None
    for record in records:
        t0 = record.ts if t0 is None else t0
        raw = record.data
        if len(raw) < _HEADER.size:
            raise TraceError(f"{path}: record {record.index} has {len(raw)} bytes, fewer than "
                             f"the {_HEADER.size}-byte USBPcap header: the file is damaged")
        (header_len, irp, status, function, info, bus, address, endpoint, transfer,
         data_length) = _HEADER.unpack_from(raw)
        control = transfer == _CONTROL
        if not _HEADER.size + control <= header_len <= len(raw):
            raise TraceError(f"{path}: record {record.index} has a USBPcap header length of "
                             f"{header_len} bytes in a {len(raw)}-byte record: the file is "
                             "damaged")
        stage = raw[_HEADER.size] if control else None
        payload = raw[header_len: header_len + min(data_length, 8 + DATA_BYTES)]
        completion = bool(info & 1)
        request = pending.get(irp)
        if request is None:
            if len(pending) >= MAX_PENDING:
                yield _abandoned(pending.pop(next(iter(pending))), t0)
            request = pending[irp] = _Request(
                record.ts, _KINDS.get(transfer, "other"), endpoint, device_key(bus, address),
                record.index)
        if not completion:
            _submitted(request, stage, payload, data_length)
            continue
        if control and stage == _STAGE_DATA:  # more stages of this request follow
            _received(request, payload, data_length)
            continue
        _received(request, payload, data_length)
        del pending[irp]
        yield _transfer(request, record, t0, status, function)
    for request in pending.values():
        yield _abandoned(request, t0 if t0 is not None else 0.0)


def _submitted(request: _Request, stage: int | None, payload: bytes, data_length: int) -> None:
    if stage == _STAGE_SETUP and len(payload) >= 8:
        request.setup = Setup.parse(payload[:8])
        request.endpoint = request.setup.request_type & 0x80
        request.out, request.out_length = payload[8:8 + DATA_BYTES], data_length - 8
    elif not request.endpoint & 0x80:
        request.out = (request.out + payload)[:DATA_BYTES]
        request.out_length += data_length


def _received(request: _Request, payload: bytes, data_length: int) -> None:
    if request.endpoint & 0x80 and data_length:
        request.received += payload[: DATA_BYTES - len(request.received)]
        request.in_length += data_length


def _transfer(request: _Request, record: Record, t0: float, status: int,
              function: int) -> Transfer:
    is_in = bool(request.endpoint & 0x80)
    ended = _STATUS.get(status, Status.ERROR)
    detail = "" if ended is Status.OK else f"USBD_STATUS 0x{status:08x}"
    if request.kind == "other":
        detail = f"URB function 0x{function:04x}"
    return Transfer(record.ts - t0, request.device, request.kind, request.endpoint,
                    request.setup, request.in_length if is_in else request.out_length,
                    bytes(request.received) if is_in else request.out, ended, detail,
                    record.index)


def _abandoned(r: _Request, t0: float) -> Transfer:
    return incomplete(r.ts - t0, r.device, r.kind, r.endpoint, r.setup, r.out_length, r.out,
                      r.index)
