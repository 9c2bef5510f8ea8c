"""Control transfers: the FX2 firmware download, and the standard requests by name.

The download (Cypress FX2 reference; `_fx2`): vendor request 0xA0 writes internal RAM and the
CPUCS register (1 holds the 8051 in reset, 0 runs it), 0xA3 external RAM through the loader.
Contiguous writes with one request make one segment event, however the loader chunks them.
Standard requests are named (USB 2.0 table 9-4); a device descriptor gives the product id.
"""

from __future__ import annotations

from .._ids import FX2_CPUCS, FX2_REQUEST_EXTERNAL, FX2_REQUEST_INTERNAL
from . import _names
from ._events import PUBLIC_FX2, DeviceState, Event, Op, Segment, status_note
from ._transfer import Status, Transfer

_VENDOR, _STANDARD = 0x40, 0x00
_TYPE_MASK = 0x60
_DESCRIPTOR_DEVICE = 1


def firmware(dev: DeviceState, tr: Transfer, fx2: tuple[int, int]) -> list[Event]:
    """A CPUCS write is an event; a RAM write extends the open segment or starts one."""
    request, address = fx2
    failed = tr.status is not Status.OK
    if request == FX2_REQUEST_INTERNAL and address == FX2_CPUCS and tr.length == 1:
        hold = tr.data[:1] == b"\x01"
        text = ("fx2 CPUCS <- 1: the 8051 held in reset" if hold
                else "fx2 CPUCS <- 0: the 8051 runs")
        op = Op("fx2 CPUCS", "1" if hold else "0", PUBLIC_FX2, PUBLIC_FX2)
        return [Event(tr.t, dev.info.key, "firmware", text + status_note(tr), tr.source,
                      {"request": request, "cpucs": int(hold), "status": tr.status},
                      (op,))]
    if continues(dev.segment, tr):
        seg = dev.segment
        assert seg is not None
        seg.end += tr.length
        seg.transfers += 1
        seg.failed += failed
    else:
        dev.segment = Segment(request, address, address + tr.length, tr.t, tr.source,
                              failed=int(failed))
    return []


def fx2_write(tr: Transfer) -> tuple[int, int] | None:
    """(request, address) of an FX2 loader write, else None."""
    s = tr.setup
    if (tr.kind == "ctrl" and s is not None and s.request_type & _TYPE_MASK == _VENDOR
            and not s.request_type & 0x80
            and s.request in (FX2_REQUEST_INTERNAL, FX2_REQUEST_EXTERNAL)):
        return s.request, s.value
    return None


def continues(seg: Segment | None, tr: Transfer) -> bool:
    fx2 = fx2_write(tr)
    return (seg is not None and fx2 is not None and fx2 == (seg.request, seg.end)
            and fx2[1] != FX2_CPUCS)


def end_segment(dev: DeviceState) -> list[Event]:
    seg, dev.segment = dev.segment, None
    if seg is None:
        return []
    ram = "internal" if seg.request == FX2_REQUEST_INTERNAL else "external"
    n = seg.end - seg.start
    text = (f"fx2 0x{seg.request:02X} {ram} RAM 0x{seg.start:04x}-0x{seg.end - 1:04x}: {n} "
            f"bytes in {seg.transfers} transfer{'s' if seg.transfers > 1 else ''}")
    if seg.failed:
        text += f" ({seg.failed} failed)"
    return [Event(seg.t, dev.info.key, "firmware", text, seg.source,
                  {"request": seg.request, "address": seg.start, "bytes": n,
                   "transfers": seg.transfers, "failed": seg.failed},
                  (Op(f"fx2 0x{seg.request:02x} write 0x{seg.start:04x}",
                      f"{n} bytes" + (" [failed]" if seg.failed else ""), PUBLIC_FX2,
                      PUBLIC_FX2),))]


def control(dev: DeviceState, tr: Transfer) -> Event:
    s = tr.setup
    key = dev.info.key
    if s is None:
        return Event(tr.t, key, "control", f"control transfer of {tr.length} bytes (its setup "
                     "packet is not in the capture)" + status_note(tr), tr.source)
    fields = {"request_type": s.request_type, "request": s.request, "value": s.value,
              "index": s.index, "length": tr.length, "status": tr.status}
    if s.request_type & _TYPE_MASK == _STANDARD:
        name = _names.STANDARD_REQUESTS.get(s.request, f"standard request {s.request}")
        text = f"{name} value 0x{s.value:04x} index 0x{s.index:04x}"
        if name == "CLEAR_FEATURE" and s.value == 0 and s.request_type & 0x1F == 2:
            text = f"CLEAR_FEATURE(ENDPOINT_HALT) of endpoint 0x{s.index:02x}"
        elif name == "GET_DESCRIPTOR" and s.value >> 8 == _DESCRIPTOR_DEVICE and \
                len(tr.data) >= 12:
            vendor = int.from_bytes(tr.data[8:10], "little")
            product = int.from_bytes(tr.data[10:12], "little")
            dev.info.product_id = product
            text = f"GET_DESCRIPTOR(DEVICE): {vendor:04x}:{product:04x}"
        return Event(tr.t, key, "control", text + status_note(tr), tr.source, fields)
    direction = "in" if s.request_type & 0x80 else "out"
    return Event(tr.t, key, "control", f"control {direction} type 0x{s.request_type:02x} "
                 f"request 0x{s.request:02x} value 0x{s.value:04x} index 0x{s.index:04x}: "
                 f"{tr.length} bytes" + status_note(tr), tr.source, fields,
                 (Op(f"control 0x{s.request_type:02x} 0x{s.request:02x}",
                     f"value 0x{s.value:04x} index 0x{s.index:04x}", dev.phase, dev.phase),))
