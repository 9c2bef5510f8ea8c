"""micam's own transfer traces (`daq.usb.TransferTrace`, JSON lines) as transfers.

Each line is validated (types and ranges) before use, and read with a bounded length, so a
damaged or foreign file is a one-line error naming the line, never a traceback or an unbounded
read. Traces written before the trace carried `bus`, `addr` and `request_type` still read:
their devices are named by micam's device name, their control transfers taken as the vendor
requests they are.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from ._errors import TraceError
from ._transfer import DATA_BYTES, Setup, Status, Transfer, device_key

MAX_LINE_BYTES = 4 * 2**20
"""Longest line read (a trace written with a large `max_data_bytes` has long hex data)."""

_VENDOR_OUT = 0x40
_ERRNO = re.compile(r"\[Errno (\d+)\]")
_STATUS = {110: Status.CANCELLED, 32: Status.STALL, 19: Status.GONE}
"""ETIMEDOUT (libusb cancels a transfer that times out), EPIPE, ENODEV."""


class _Line(BaseModel):
    """One line of a trace (see `daq.usb._trace`)."""

    model_config = ConfigDict(extra="ignore", frozen=True)

    t: float = Field(ge=0)
    dev: str = Field(max_length=200)
    bus: int | None = Field(default=None, ge=0, le=0xFFFF)
    addr: int | None = Field(default=None, ge=0, le=0xFF)
    kind: Literal["ctrl", "bulk"]
    dir: Literal["in", "out"]
    ep: int | None = Field(default=None, ge=0, le=0xFF)
    request_type: int | None = Field(default=None, ge=0, le=0xFF)
    request: int | None = Field(default=None, ge=0, le=0xFF)
    value: int | None = Field(default=None, ge=0, le=0xFFFF)
    index: int | None = Field(default=None, ge=0, le=0xFFFF)
    len: int = Field(ge=0, le=2**32)
    status: str = Field(max_length=500)
    data: str = Field(default="", pattern=r"^([0-9a-f]{2})*$")

    @field_validator("t")
    @classmethod
    def _finite(cls, t: float) -> float:
        if not math.isfinite(t):
            raise ValueError("must be a finite number of seconds")
        return t


def transfers(path: Path, f: BinaryIO) -> Iterator[Transfer]:
    """The transfers of a micam trace, in file order."""
    t0: float | None = None
    number = 0
    while line := f.readline(MAX_LINE_BYTES + 1):
        number += 1
        if len(line) > MAX_LINE_BYTES:
            raise TraceError(f"{path}: line {number} is longer than "
                             f"{MAX_LINE_BYTES // 2**20} MiB: not a micam transfer trace")
        if not line.strip():
            continue
        entry = _parse(path, number, line)
        t0 = entry.t if t0 is None else t0
        yield _transfer(entry, entry.t - t0, number - 1)


def _parse(path: Path, number: int, line: bytes) -> _Line:
    try:
        return _Line.model_validate(json.loads(line))
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise TraceError(f"{path}: line {number} is not JSON: the trace is damaged") from None
    except ValidationError as e:
        first = e.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "the line"
        raise TraceError(f"{path}: line {number}: {where}: {first['msg']}; not a micam "
                         "transfer trace, or a damaged one") from None


def _transfer(entry: _Line, t: float, source: int) -> Transfer:
    device = (device_key(entry.bus, entry.addr) if entry.bus is not None
              and entry.addr is not None else entry.dev)
    setup = None
    if entry.kind == "ctrl":
        direction = 0x80 if entry.dir == "in" else 0x00
        request_type = entry.request_type if entry.request_type is not None else (
            _VENDOR_OUT | direction)
        setup = Setup(request_type, entry.request or 0, entry.value or 0, entry.index or 0,
                      entry.len)
        endpoint = request_type & 0x80
    else:
        endpoint = (entry.ep or 0) | (0x80 if entry.dir == "in" else 0)
    if entry.status == "ok":
        status, detail = Status.OK, ""
    else:
        m = _ERRNO.search(entry.status)
        status = _STATUS.get(int(m.group(1)), Status.ERROR) if m else Status.ERROR
        detail = entry.status
    return Transfer(t, device, entry.kind, endpoint, setup, entry.len,
                    bytes.fromhex(entry.data)[:DATA_BYTES], status, detail, source,
                    name=entry.dev)
