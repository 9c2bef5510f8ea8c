"""Transfers decoded with the driver's own protocol module: what each one means.

For every device of a trace the decoder keeps what the traffic has told so far (the registers
written, the read command awaiting its reply, the model from VERSION_ID, the serial from the
EEPROM, the product id from a device descriptor or micam's device name) and turns transfers
into events:

- the FX2 firmware download (vendor requests 0xA0 / 0xA3): CPUCS writes, and contiguous RAM
  writes merged into one event per segment (however the loader chunks them);
- commands on 0x01 by name with their fields, registers by name and bits (`decode_command`);
- replies on 0x81 decoded against the command they answer (`decode_reply`): values by
  register, the board variant, the EEPROM serial; a reply of the wrong length is named;
- asynchronous messages on 0x88 (`AsyncMessage`);
- the streams on 0x82 (inputs) and 0x06 (outputs), summarised per run: transfers, bytes,
  frames of the enabled channels (`ScanSettings.from_registers` on the registers written, and
  `STREAM_DTYPE`), a torn last frame, the scan length, the first frame's codes;
- standard control requests by name; empty reads of the stream and message endpoints (the
  driver's and the vendor's polling) as "poll" events, which `show` hides unless asked.

Each event also carries its `ops`: the steps `diff` aligns and compares, each with what it
rests on: a guess of `_unpublished` (a `Guess` value), a public fact, or a choice of micam's.
Register reads and writes are one op per register, so packaging (one W_MULTI_WORD_LB or
several W_SINGLE_WORD_LB) does not count as a difference.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from .._errors import ProtocolError
from .._ids import (
    EP_CMD_IN,
    EP_CMD_OUT,
    EP_MSG_IN,
    EP_STREAM_IN,
    EP_STREAM_OUT,
    FX2_CPUCS,
    FX2_REQUEST_EXTERNAL,
    FX2_REQUEST_INTERNAL,
)
from .._protocol import (
    AsyncMessage,
    CommandCode,
    ReadI2cBytes,
    ReadWord,
    ReadWords,
    StartSubsystem,
    StopSubsystem,
    WriteWord,
    WriteWords,
    decode_command,
)
from .._registers import EEPROM_I2C_ADDRESS, EEPROM_SERIAL, INIT_SEQUENCE, IoOp, Reg
from .._unpublished import DT9816_VERSION_IDS, STREAM_DTYPE, Guess, ScanSettings, decode_stream
from . import _names
from ._transfer import Status, Transfer

PUBLIC_FX2 = "public: the FX2 firmware download (daq/usb/_fx2.py)"
PUBLIC_IDENTIFY = "public: identification by VERSION_ID and the EEPROM (daq/usb/_board.py)"
PUBLIC_INIT = "public: the probe-time register writes (daq/usb/_registers.py INIT_SEQUENCE)"
PUBLIC_PROTOCOL = "public: the command packets and messages (daq/usb/_protocol.py)"
PUBLIC_VERSIONS = "public: the DT9836 version register values (daq/_models.py)"
MICAM_READBACK = "micam: the scan set-up read-back (daq/usb/_board.py configure)"

_SCAN_REGISTERS = {Reg.MISC_CTRLS, Reg.INPUT_CONTROL0, Reg.INPUT_CHAN_MASK_LO,
                   Reg.INPUT_CHAN_MASK_HI, Reg.SAMPLES_PER_TRIG_LO, Reg.SAMPLES_PER_TRIG_HI,
                   Reg.OUTPUT_CONTROL}
_CLOCK_REGISTERS = {Reg.IN_SAMPLE_CLK_PERIOD_LO, Reg.IN_SAMPLE_CLK_PERIOD_HI,
                    Reg.OUT_SAMPLE_CLK_PERIOD_LO, Reg.OUT_SAMPLE_CLK_PERIOD_HI}
_INIT_ONLY = {Reg.INT_STATUS, Reg.INT_MASK, Reg.DIG_IN_CTRL_STAT}
_VENDOR, _STANDARD = 0x40, 0x00
_TYPE_MASK = 0x60
_DESCRIPTOR_DEVICE = 1
_MAX_FIRST_VALUES = 16


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
class _Run:
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
class _Segment:
    """Contiguous FX2 RAM writes with one request."""

    request: int
    start: int
    end: int
    t: float
    source: int
    transfers: int = 1
    failed: int = 0


@dataclass
class _Device:
    info: DeviceInfo
    registers: dict[int, int] = field(default_factory=dict)
    pending: tuple[Any, Transfer] | None = None
    configured: bool = False
    phase: str = PUBLIC_PROTOCOL
    runs: dict[int, _Run] = field(default_factory=dict)
    segment: _Segment | None = None


class Decoder:
    """Decodes the transfers of one trace, in order; see the module docstring."""

    def __init__(self) -> None:
        self._devices: dict[str, _Device] = {}
        self.transfers = 0
        self.polls = 0

    @property
    def devices(self) -> dict[str, DeviceInfo]:
        """What the trace has told so far about each device, by device key."""
        return {k: d.info for k, d in self._devices.items()}

    def feed(self, tr: Transfer) -> list[Event]:
        """The events that `tr` completes (a stream run or firmware segment may end here)."""
        self.transfers += 1
        dev = self._device(tr)
        events: list[Event] = []
        fx2 = _fx2_write(tr)
        if fx2 is None or not _continues(dev.segment, tr):
            events += _end_segment(dev)
        if fx2 is not None:
            events += self._firmware(dev, tr, fx2)
        elif tr.kind == "ctrl":
            events.append(_control(dev, tr))
        elif tr.kind in ("bulk", "intr"):
            events += self._bulk(dev, tr)
        else:
            events.append(Event(tr.t, dev.info.key, "other", f"{tr.kind} transfer on endpoint "
                                f"0x{tr.endpoint:02x}, {tr.length} bytes (not decoded)"
                                + _status(tr), tr.source))
        return events

    def finish(self) -> list[Event]:
        """The events still open at the end of the trace (stream runs, segments, replies)."""
        events: list[Event] = []
        for dev in self._devices.values():
            events += _end_segment(dev) + _end_runs(dev) + _unanswered(dev)
        return sorted(events, key=lambda e: e.t)

    def _device(self, tr: Transfer) -> _Device:
        dev = self._devices.get(tr.device)
        if dev is None:
            dev = self._devices[tr.device] = _Device(DeviceInfo(tr.device))
        if tr.name is not None:
            dev.info.name = tr.name
            _product_from_name(dev.info, tr.name)
        return dev

    def _firmware(self, dev: _Device, tr: Transfer, fx2: tuple[int, int]) -> list[Event]:
        request, address = fx2
        failed = tr.status is not Status.OK
        if request == FX2_REQUEST_INTERNAL and address == FX2_CPUCS and tr.length == 1:
            hold = tr.data[:1] == b"\x01"
            text = ("fx2 CPUCS <- 1: the 8051 held in reset" if hold
                    else "fx2 CPUCS <- 0: the 8051 runs")
            op = Op("fx2 CPUCS", "1" if hold else "0", PUBLIC_FX2, PUBLIC_FX2)
            return [Event(tr.t, dev.info.key, "firmware", text + _status(tr), tr.source,
                          {"request": request, "cpucs": int(hold), "status": tr.status},
                          (op,))]
        if _continues(dev.segment, tr):
            seg = dev.segment
            assert seg is not None
            seg.end += tr.length
            seg.transfers += 1
            seg.failed += failed
        else:
            dev.segment = _Segment(request, address, address + tr.length, tr.t, tr.source,
                                   failed=int(failed))
        return []

    def _bulk(self, dev: _Device, tr: Transfer) -> list[Event]:
        ep = tr.endpoint
        if ep == EP_CMD_OUT:
            return _end_runs(dev, only=EP_STREAM_OUT) + self._command(dev, tr)
        if ep == EP_CMD_IN:
            return [_reply(dev, tr)]
        if ep in (EP_STREAM_IN, EP_STREAM_OUT, EP_MSG_IN) and tr.length == 0 and (
                tr.status in (Status.OK, Status.CANCELLED)):
            self.polls += 1
            return [Event(tr.t, dev.info.key, "poll", f"bulk in 0x{ep:02x}: nothing "
                          f"({tr.status})", tr.source)]
        if ep == EP_MSG_IN:
            return [_message(dev, tr)]
        if ep in (EP_STREAM_IN, EP_STREAM_OUT) and tr.length:
            _extend_run(dev, tr)
            return []
        direction = "in" if tr.is_in else "out"
        return [Event(tr.t, dev.info.key, "bulk", f"bulk {direction} 0x{ep:02x}: {tr.length} "
                      f"bytes {tr.data[:16].hex()}" + _status(tr), tr.source,
                      {"endpoint": ep, "length": tr.length, "status": tr.status},
                      (Op(f"bulk {direction} 0x{ep:02x}", f"{tr.length} bytes", dev.phase,
                          dev.phase),))]

    def _command(self, dev: _Device, tr: Transfer) -> list[Event]:
        events = _unanswered(dev)
        packet = tr.data[: tr.length]
        try:
            command = decode_command(packet)
        except ProtocolError as e:
            name = _code_name(packet)
            events.append(Event(tr.t, dev.info.key, "command", f"command {name}: {e}; bytes "
                                f"{packet[:16].hex()}" + _status(tr), tr.source,
                                {"command": name, "length": tr.length, "status": tr.status},
                                (Op(f"command {name}", packet.hex(), dev.phase,
                                    dev.phase),)))
            return events
        if isinstance(command, StartSubsystem | StopSubsystem):
            events += _end_runs(dev)
        text, fields, ops = _describe(dev, command)
        if tr.status is not Status.OK:
            ops = tuple(Op(o.key, f"{o.value} [{tr.status}]", o.basis, o.value_basis)
                        for o in ops)
        if hasattr(command, "reply_length"):
            dev.pending = (command, tr)
        events.append(Event(tr.t, dev.info.key, "command", text + _status(tr), tr.source,
                            {**fields, "status": tr.status}, ops))
        if ops:
            dev.phase = ops[-1].basis
        return events


def decode(transfers: Iterable[Transfer]) -> Iterator[Event]:
    """The events of a trace in order (a convenience over `Decoder`)."""
    decoder = Decoder()
    for tr in transfers:
        yield from decoder.feed(tr)
    yield from decoder.finish()


# -- commands and replies ---------------------------------------------------------------------


def _describe(dev: _Device, command: Any) -> tuple[str, dict[str, Any], tuple[Op, ...]]:
    name = command.code.name
    fields: dict[str, Any] = {"command": name}
    if isinstance(command, WriteWord | WriteWords):
        writes = ((command.address, command.value),) if isinstance(command, WriteWord) \
            else command.writes
        ops = []
        for address, v in writes:
            basis = _write_basis(dev, address, v)
            dev.registers[address] = v
            ops.append(Op(f"write {_names.register(address)}", f"0x{v:04x}", basis, basis))
        fields["writes"] = [{"register": _names.register(a), "address": a, "value": v}
                            for a, v in writes]
        text = ", ".join(f"{_names.register(a)} = {_names.value(a, v)}" for a, v in writes)
        return f"{name} {text}", fields, tuple(ops)
    if isinstance(command, ReadWord | ReadWords):
        addresses = (command.address,) if isinstance(command, ReadWord) else command.addresses
        fields["registers"] = [_names.register(a) for a in addresses]
        return f"{name} {', '.join(_names.register(a) for a in addresses)}", fields, ()
    if isinstance(command, ReadI2cBytes):
        fields["reads"] = [{"device": d, "register": r} for d, r in command.reads]
        regs = " ".join(f"0x{d:02x}:{r}" for d, r in command.reads)
        return f"{name} {regs}{_eeprom_note(command)}", fields, ()
    assert isinstance(command, StartSubsystem | StopSubsystem)
    sub = command.subsystem.name
    fields.update(subsystem=sub, ext_trig=command.ext_trig)
    start = isinstance(command, StartSubsystem)
    basis = Guess.ARM_COMMANDS if start else Guess.STOP_COMMANDS
    op = Op(f"{name} {sub}", f"ExtTrig 0x{command.ext_trig:04x}", basis,
            Guess.EXT_TRIG_POSITIVE_EDGE if start else basis)
    return f"{name} {sub} ExtTrig 0x{command.ext_trig:04x}", fields, (op,)


def _reply(dev: _Device, tr: Transfer) -> Event:
    pending, dev.pending = dev.pending, None
    key = dev.info.key
    if pending is None:
        return Event(tr.t, key, "reply", f"reply of {tr.length} bytes with no read command "
                     "before it" + _status(tr), tr.source, {"length": tr.length},
                     (Op("reply without a command", f"{tr.length} bytes", dev.phase,
                         dev.phase),))
    command, _ = pending
    name = command.code.name
    if tr.status is not Status.OK or tr.length == 0:
        return Event(tr.t, key, "reply", f"no reply to {name}" + _status(tr), tr.source,
                     {"command": name, "status": tr.status},
                     (Op(f"reply to {name}", f"none [{tr.status}]", dev.phase, dev.phase),))
    try:
        values = command.decode_reply(tr.data[: tr.length])
    except ProtocolError:
        expected = command.reply_length()
        return Event(tr.t, key, "reply", f"reply to {name} of {tr.length} bytes where "
                     f"{expected} were expected", tr.source,
                     {"command": name, "length": tr.length, "expected": expected},
                     (Op(f"reply to {name}", f"{tr.length} bytes where {expected} expected",
                         dev.phase, dev.phase),))
    if isinstance(command, ReadI2cBytes):
        return _eeprom_reply(dev, tr, command, values)
    addresses = (command.address,) if isinstance(command, ReadWord) else command.addresses
    ops, parts = [], []
    for address, v in zip(addresses, values, strict=True):
        basis, value_basis = _read_basis(dev, address, v)
        ops.append(Op(f"read {_names.register(address)}", f"0x{v:04x}", basis, value_basis))
        text = f"{_names.register(address)} = {_names.value(address, v)}"
        if address == Reg.VERSION_ID:
            dev.info.model = _names.VARIANTS.get(v)
            text += f" ({dev.info.model or 'no known variant'})"
        parts.append(text)
    return Event(tr.t, key, "reply", "reply " + ", ".join(parts), tr.source,
                 {"command": name, "values": [{"register": _names.register(a), "value": v}
                                              for a, v in zip(addresses, values, strict=True)]},
                 tuple(ops))


def _eeprom_reply(dev: _Device, tr: Transfer, command: ReadI2cBytes,
                  values: tuple[int, ...]) -> Event:
    ops = tuple(Op(f"read I2C 0x{d:02x}:{r}", f"0x{v:02x}", PUBLIC_IDENTIFY, PUBLIC_IDENTIFY)
                for (d, r), v in zip(command.reads, values, strict=True))
    text = "reply " + " ".join(f"{v:02x}" for v in values)
    if command.reads == tuple((EEPROM_I2C_ADDRESS, r) for r in EEPROM_SERIAL):
        dev.info.serial = str(int.from_bytes(bytes(values), "little"))
        text += f" (EEPROM serial {dev.info.serial})"
    return Event(tr.t, dev.info.key, "reply", text, tr.source,
                 {"command": command.code.name, "bytes": list(values),
                  "serial": dev.info.serial}, ops)


def _unanswered(dev: _Device) -> list[Event]:
    """A read command whose reply never came (the trace moved on, or ended)."""
    if dev.pending is None:
        return []
    (command, tr), dev.pending = dev.pending, None
    name = command.code.name
    return [Event(tr.t, dev.info.key, "reply", f"no reply to {name} in the trace", tr.source,
                  {"command": name}, (Op(f"reply to {name}", "none", dev.phase, dev.phase),))]


def _eeprom_note(command: ReadI2cBytes) -> str:
    if all(d == EEPROM_I2C_ADDRESS for d, _ in command.reads):
        return " (EEPROM)"
    return ""


def _code_name(packet: bytes) -> str:
    if not packet:
        return "(empty packet)"
    try:
        return CommandCode(packet[0]).name
    except ValueError:
        return f"code {packet[0]}"


def _write_basis(dev: _Device, address: int, value: int) -> str:
    """What a register write rests on: the guess (or fact) that chose its value."""
    if address == Reg.IO_OP_CONTROL:
        io = IoOp(value & sum(IoOp))
        if io & (IoOp.INPUT_SCAN_ARM | IoOp.OUTPUT_ARM):
            return Guess.ARM_COMMANDS
        if io & (IoOp.INPUT_SOFT_TRIGGER | IoOp.OUTPUT_SOFT_TRIGGER):
            return Guess.SOFTWARE_TRIGGER_COMMANDS
        if io & IoOp.INPUT_SCAN_STOP:
            return Guess.STOP_COMMANDS
        return PUBLIC_INIT
    if address in _CLOCK_REGISTERS:
        dev.configured = True
        return Guess.CLOCK_PERIOD
    if address in _INIT_ONLY:
        return PUBLIC_INIT
    if address in _SCAN_REGISTERS:
        if not dev.configured and (address, value) in INIT_SEQUENCE:
            return PUBLIC_INIT
        dev.configured = True
        return Guess.SCAN_REGISTERS
    return dev.phase  # a register the map does not name: judged by where it is written


def _read_basis(dev: _Device, address: int, value: int) -> tuple[str, str]:
    if address == Reg.VERSION_ID:
        dt9816 = value in DT9816_VERSION_IDS or dev.info.model in DT9816_VERSION_IDS.values()
        return PUBLIC_IDENTIFY, Guess.DT9816_VERSION_IDS if dt9816 else PUBLIC_VERSIONS
    if address in _CLOCK_REGISTERS:
        return MICAM_READBACK, Guess.CLOCK_PERIOD
    if address in _SCAN_REGISTERS:
        return MICAM_READBACK, Guess.SCAN_REGISTERS
    return dev.phase, dev.phase


def _message(dev: _Device, tr: Transfer) -> Event:
    try:
        message = AsyncMessage.decode(tr.data[: tr.length])
    except ProtocolError as e:
        return Event(tr.t, dev.info.key, "message", f"message: {e}; bytes "
                     f"{tr.data[:16].hex()}", tr.source, {"length": tr.length},
                     (Op("message", tr.data[:16].hex(), PUBLIC_PROTOCOL, PUBLIC_PROTOCOL),))
    name = message.kind.name
    return Event(tr.t, dev.info.key, "message", f"message {name} value {message.value}",
                 tr.source, {"message": name, "value": message.value},
                 (Op(f"message {name}", str(message.value), PUBLIC_PROTOCOL,
                     PUBLIC_PROTOCOL),))


# -- streams ----------------------------------------------------------------------------------


def _extend_run(dev: _Device, tr: Transfer) -> None:
    run = dev.runs.get(tr.endpoint)
    if run is None:
        run = dev.runs[tr.endpoint] = _Run(tr.endpoint, tr.t, tr.source)
    run.t_last = tr.t
    run.transfers += 1
    run.length += tr.length
    run.failed += tr.status is not Status.OK
    if not run.first:
        run.first = tr.data


def _end_runs(dev: _Device, only: int | None = None) -> list[Event]:
    events = []
    for ep in [e for e in dev.runs if only is None or e == only]:
        events.append(_stream_event(dev, dev.runs.pop(ep)))
    return events


def _stream_event(dev: _Device, run: _Run) -> Event:
    settings = ScanSettings.from_registers(lambda a: dev.registers.get(a, 0))
    is_in = run.endpoint == EP_STREAM_IN
    channels = settings.inputs if is_in else settings.outputs
    where = f"stream {'in' if is_in else 'out'} 0x{run.endpoint:02x}"
    head = f"{where}: {run.transfers} transfers, {run.length} bytes"
    fields: dict[str, Any] = {"endpoint": run.endpoint, "transfers": run.transfers,
                              "bytes": run.length, "t_end": round(run.t_last, 6),
                              "channels": list(channels)}
    presence = Guess.STREAM_DTYPE if is_in else Guess.ARM_COMMANDS
    if not channels:
        return Event(run.t, dev.info.key, "stream", head + " (no channels enabled in the "
                     "registers seen: frames unknown)", run.source, fields,
                     (Op(where, "frames unknown", presence, Guess.STREAM_DTYPE),))
    frame = STREAM_DTYPE.itemsize * len(channels)
    frames, torn = divmod(run.length, frame)
    text = f"{head} = {frames} frames of {len(channels)} channels {list(channels)}"
    verdict = f"{len(channels)}-channel frames, " + ("whole" if not torn else "torn")
    if torn:
        text += f" and {torn} bytes of a torn frame"
    if is_in:
        relation = _against_scan(frames, settings.samples)
        text += f"; the scan: {settings.samples or 'continuous'}" + (
            f" samples ({relation})" if settings.samples else "")
        verdict += f", {relation}"
    first = run.first[: frame * (len(run.first) // frame)][:frame]
    if first:
        codes = decode_stream(first, len(channels))[0][:_MAX_FIRST_VALUES]
        fields["first_frame"] = [int(c) for c in codes]
        text += f"; first frame {' '.join(str(int(c)) for c in codes)}"
    if run.failed:
        text += f"; {run.failed} transfers ended early (cancelled or failed)"
    fields.update(frames=frames, torn_bytes=torn)
    return Event(run.t, dev.info.key, "stream", text, run.source, fields,
                 (Op(where, verdict, presence, Guess.STREAM_DTYPE),))


def _against_scan(frames: int, samples: int) -> str:
    if not samples:
        return "continuous scan"
    if frames == samples:
        return "as many frames as the scan's samples"
    return "more frames than the scan's samples" if frames > samples else (
        "fewer frames than the scan's samples")


# -- control transfers ------------------------------------------------------------------------


def _fx2_write(tr: Transfer) -> tuple[int, int] | None:
    """(request, address) of an FX2 loader write, else None."""
    s = tr.setup
    if (tr.kind == "ctrl" and s is not None and s.request_type & _TYPE_MASK == _VENDOR
            and not s.request_type & 0x80
            and s.request in (FX2_REQUEST_INTERNAL, FX2_REQUEST_EXTERNAL)):
        return s.request, s.value
    return None


def _continues(seg: _Segment | None, tr: Transfer) -> bool:
    fx2 = _fx2_write(tr)
    return (seg is not None and fx2 is not None and fx2 == (seg.request, seg.end)
            and fx2[1] != FX2_CPUCS)


def _end_segment(dev: _Device) -> list[Event]:
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


def _control(dev: _Device, tr: Transfer) -> Event:
    s = tr.setup
    key = dev.info.key
    if s is None:
        return Event(tr.t, key, "control", f"control transfer of {tr.length} bytes (its setup "
                     "packet is not in the capture)" + _status(tr), tr.source)
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
        return Event(tr.t, key, "control", text + _status(tr), tr.source, fields)
    direction = "in" if s.request_type & 0x80 else "out"
    return Event(tr.t, key, "control", f"control {direction} type 0x{s.request_type:02x} "
                 f"request 0x{s.request:02x} value 0x{s.value:04x} index 0x{s.index:04x}: "
                 f"{tr.length} bytes" + _status(tr), tr.source, fields,
                 (Op(f"control 0x{s.request_type:02x} 0x{s.request:02x}",
                     f"value 0x{s.value:04x} index 0x{s.index:04x}", dev.phase, dev.phase),))


def _status(tr: Transfer) -> str:
    if tr.status is Status.OK:
        return ""
    return f" [{tr.status}{': ' + tr.detail if tr.detail else ''}]"


def _product_from_name(info: DeviceInfo, name: str) -> None:
    """micam names a device by its USB location until identified: "0867:3698 at bus 1 ..."."""
    vid, sep, rest = name.partition(":")
    if sep and vid == "0867" and len(rest) >= 4:
        try:
            info.product_id = int(rest[:4], 16)
        except ValueError:
            pass
