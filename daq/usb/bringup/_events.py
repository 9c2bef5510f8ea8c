"""What the decoder produces and keeps: events, their diff steps, and each device's state.

An `Event` is one decoded step of a trace; its `Op`s are what `diff` aligns, each with its
basis: a `Guess` of `_unpublished` (the value is the guess's name), a public fact ("public:
..."), or a choice of micam's ("micam: ..."). `DeviceState` is what the traffic has told the
decoder about one device so far.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ._transfer import Status, Transfer

PUBLIC_FX2 = "public: the FX2 firmware download (daq/usb/_fx2.py)"
PUBLIC_IDENTIFY = "public: identification by VERSION_ID and the EEPROM (daq/usb/_board.py)"
PUBLIC_INIT = "public: the probe-time register writes (daq/usb/_registers.py INIT_SEQUENCE)"
PUBLIC_PROTOCOL = "public: the command packets and messages (daq/usb/_protocol.py)"
PUBLIC_VERSIONS = "public: the DT9836 version register values (daq/_models.py)"
MICAM_READBACK = "micam: the scan set-up read-back (daq/usb/_board.py configure)"

@dataclass(frozen=True)
class Op:
    """One step of a trace as `diff` aligns it.

    Attributes:
        key: what the step is ("write INPUT_CONTROL0", "START_SUBSYSTEM DA", "stream in
            0x82"); steps with equal keys align.
        value: what it carried; compared when the keys align.
        basis: what the step's presence and place rest on (a `Guess` value, or a "public:"
            fact, or a "micam:" choice).
        value_basis: what its value rests on.
    """

    key: str
    value: str
    basis: str
    value_basis: str


@dataclass(frozen=True)
class Event:
    """One decoded step of a trace.

    Attributes:
        t: seconds since the first record of the file (a stream run: its first transfer).
        device: "BUS:ADDRESS" (or micam's device name in an older trace).
        kind: "firmware", "command", "reply", "message", "stream", "control", "bulk",
            "poll" or "other".
        text: the step in words.
        source: record (or line) number in the file, from 0.
        fields: the decoded fields, for JSON output.
        ops: the steps `diff` compares.
    """

    t: float
    device: str
    kind: str
    text: str
    source: int
    fields: Mapping[str, Any] = field(default_factory=dict)
    ops: tuple[Op, ...] = ()

    def as_json(self) -> dict[str, Any]:
        return {"t": round(self.t, 6), "device": self.device, "kind": self.kind,
                "text": self.text, "record": self.source, **self.fields}


@dataclass
class DeviceInfo:
    """What a trace tells about one device."""

    key: str
    product_id: int | None = None
    model: str | None = None
    serial: str | None = None
    name: str | None = None

    def label(self) -> str:
        parts = [self.key]
        if self.product_id is not None:
            parts.append(f"0867:{self.product_id:04x}")
        if self.model or self.serial:
            parts.append(f"{self.model or '?'} serial {self.serial or '?'}")
        return " ".join(parts)


@dataclass
class Run:
    """Consecutive stream transfers on one endpoint of one device."""

    endpoint: int
    t: float
    source: int
    t_last: float = 0.0
    transfers: int = 0
    length: int = 0
    first: bytes = b""
    failed: int = 0


@dataclass
class Segment:
    """Contiguous FX2 RAM writes with one request."""

    request: int
    start: int
    end: int
    t: float
    source: int
    transfers: int = 1
    failed: int = 0


@dataclass
class DeviceState:
    info: DeviceInfo
    registers: dict[int, int] = field(default_factory=dict)
    pending: tuple[Any, Transfer] | None = None
    configured: bool = False
    phase: str = PUBLIC_PROTOCOL
    runs: dict[int, Run] = field(default_factory=dict)
    segment: Segment | None = None



def status_note(tr: Transfer) -> str:
    if tr.status is Status.OK:
        return ""
    return f" [{tr.status}{': ' + tr.detail if tr.detail else ''}]"
