"""Transfers decoded with the driver's own protocol module: what each one means.

For every device of a trace the decoder keeps what the traffic has told so far (the registers
written, the read command awaiting its reply, the model from VERSION_ID, the serial from the
EEPROM, the product id from a device descriptor or micam's device name) and turns transfers
into events:

- the FX2 firmware download and the standard requests (`_control`);
- commands on 0x01 by name with their fields, registers by name and bits (`decode_command`);
- replies on 0x81 decoded against the command they answer (`decode_reply`): values by
  register, the board variant, the EEPROM serial; a reply of the wrong length is named;
- asynchronous messages on 0x88 (`AsyncMessage`);
- the streams on 0x82 (inputs) and 0x06 (outputs), summarised per run (`_streams`): bytes,
  frames of the enabled channels, a torn last frame, the scan length, the first frame;
- empty reads of the stream and message endpoints (the driver's and the vendor's polling) as
  "poll" events, which `show` hides unless asked.

Each event also carries its `ops`: the steps `diff` aligns and compares, each with what it
rests on: a guess of `_unpublished` (a `Guess` value), a public fact, or a choice of micam's.
Register reads and writes are one op per register, so packaging (one W_MULTI_WORD_LB or
several W_SINGLE_WORD_LB) does not count as a difference.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import Any

from .._errors import ProtocolError
from .._ids import EP_CMD_IN, EP_CMD_OUT, EP_MSG_IN, EP_STREAM_IN, EP_STREAM_OUT
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
from .._unpublished import DT9816_VERSION_IDS, Guess
from . import _names
from ._control import continues, control, end_segment, firmware, fx2_write
from ._events import (
    MICAM_READBACK,
    PUBLIC_IDENTIFY,
    PUBLIC_INIT,
    PUBLIC_PROTOCOL,
    PUBLIC_VERSIONS,
    DeviceInfo,
    DeviceState,
    Event,
    Op,
    status_note,
)
from ._streams import end_runs, extend_run
from ._transfer import Status, Transfer

_SCAN_REGISTERS = {Reg.MISC_CTRLS, Reg.INPUT_CONTROL0, Reg.INPUT_CHAN_MASK_LO,
                   Reg.INPUT_CHAN_MASK_HI, Reg.SAMPLES_PER_TRIG_LO, Reg.SAMPLES_PER_TRIG_HI,
                   Reg.OUTPUT_CONTROL}
_CLOCK_REGISTERS = {Reg.IN_SAMPLE_CLK_PERIOD_LO, Reg.IN_SAMPLE_CLK_PERIOD_HI,
                    Reg.OUT_SAMPLE_CLK_PERIOD_LO, Reg.OUT_SAMPLE_CLK_PERIOD_HI}
_INIT_ONLY = {Reg.INT_STATUS, Reg.INT_MASK, Reg.DIG_IN_CTRL_STAT}


class Decoder:
    """Decodes the transfers of one trace, in order; see the module docstring."""

    def __init__(self) -> None:
        self._devices: dict[str, DeviceState] = {}
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
        fx2 = fx2_write(tr)
        if fx2 is None or not continues(dev.segment, tr):
            events += end_segment(dev)
        if fx2 is not None:
            events += firmware(dev, tr, fx2)
        elif tr.kind == "ctrl":
            events.append(control(dev, tr))
        elif tr.kind in ("bulk", "intr"):
            events += self._bulk(dev, tr)
        else:
            events.append(Event(tr.t, dev.info.key, "other", f"{tr.kind} transfer on endpoint "
                                f"0x{tr.endpoint:02x}, {tr.length} bytes (not decoded)"
                                + status_note(tr), tr.source))
        return events

    def finish(self) -> list[Event]:
        """The events still open at the end of the trace (stream runs, segments, replies)."""
        events: list[Event] = []
        for dev in self._devices.values():
            events += end_segment(dev) + end_runs(dev) + _unanswered(dev)
        return sorted(events, key=lambda e: e.t)

    def _device(self, tr: Transfer) -> DeviceState:
        dev = self._devices.get(tr.device)
        if dev is None:
            dev = self._devices[tr.device] = DeviceState(DeviceInfo(tr.device))
        if tr.name is not None:
            dev.info.name = tr.name
            _product_from_name(dev.info, tr.name)
        return dev

    def _bulk(self, dev: DeviceState, tr: Transfer) -> list[Event]:
        ep = tr.endpoint
        if ep == EP_CMD_OUT:
            return end_runs(dev, only=EP_STREAM_OUT) + self._command(dev, tr)
        if ep == EP_CMD_IN:
            return [_reply(dev, tr)]
        if ep in (EP_STREAM_IN, EP_STREAM_OUT, EP_MSG_IN) and tr.length == 0 and (
                tr.status in (Status.OK, Status.CANCELLED)):
            self.polls += 1
            direction = "in" if tr.is_in else "out"
            return [Event(tr.t, dev.info.key, "poll", f"bulk {direction} 0x{ep:02x}: nothing "
                          f"({tr.status})", tr.source)]
        if ep == EP_MSG_IN:
            return [_message(dev, tr)]
        if ep in (EP_STREAM_IN, EP_STREAM_OUT) and tr.length:
            extend_run(dev, tr)
            return []
        direction = "in" if tr.is_in else "out"
        return [Event(tr.t, dev.info.key, "bulk", f"bulk {direction} 0x{ep:02x}: {tr.length} "
                      f"bytes {tr.data[:16].hex()}" + status_note(tr), tr.source,
                      {"endpoint": ep, "length": tr.length, "status": tr.status},
                      (Op(f"bulk {direction} 0x{ep:02x}", f"{tr.length} bytes", dev.phase,
                          dev.phase),))]

    def _command(self, dev: DeviceState, tr: Transfer) -> list[Event]:
        events = _unanswered(dev)
        packet = tr.data[: tr.length]
        try:
            command = decode_command(packet)
        except ProtocolError as e:
            name = _code_name(packet)
            events.append(Event(tr.t, dev.info.key, "command", f"command {name}: {e}; bytes "
                                f"{packet[:16].hex()}" + status_note(tr), tr.source,
                                {"command": name, "length": tr.length, "status": tr.status},
                                (Op(f"command {name}", packet.hex(), dev.phase,
                                    dev.phase),)))
            return events
        if isinstance(command, StartSubsystem | StopSubsystem):
            events += end_runs(dev)
        text, fields, ops = _describe(dev, command)
        if tr.status is not Status.OK:
            ops = tuple(Op(o.key, f"{o.value} [{tr.status}]", o.basis, o.value_basis)
                        for o in ops)
        if hasattr(command, "reply_length"):
            dev.pending = (command, tr)
        events.append(Event(tr.t, dev.info.key, "command", text + status_note(tr), tr.source,
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


def _describe(dev: DeviceState, command: Any) -> tuple[str, dict[str, Any], tuple[Op, ...]]:
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


def _reply(dev: DeviceState, tr: Transfer) -> Event:
    pending, dev.pending = dev.pending, None
    key = dev.info.key
    if pending is None:
        return Event(tr.t, key, "reply", f"reply of {tr.length} bytes with no read command "
                     "before it" + status_note(tr), tr.source, {"length": tr.length},
                     (Op("reply without a command", f"{tr.length} bytes", dev.phase,
                         dev.phase),))
    command, _ = pending
    name = command.code.name
    if tr.status is not Status.OK or tr.length == 0:
        return Event(tr.t, key, "reply", f"no reply to {name}" + status_note(tr), tr.source,
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


def _eeprom_reply(dev: DeviceState, tr: Transfer, command: ReadI2cBytes,
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


def _unanswered(dev: DeviceState) -> list[Event]:
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


def _write_basis(dev: DeviceState, address: int, value: int) -> str:
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


def _read_basis(dev: DeviceState, address: int, value: int) -> tuple[str, str]:
    if address == Reg.VERSION_ID:
        dt9816 = value in DT9816_VERSION_IDS or dev.info.model in DT9816_VERSION_IDS.values()
        return PUBLIC_IDENTIFY, Guess.DT9816_VERSION_IDS if dt9816 else PUBLIC_VERSIONS
    if address in _CLOCK_REGISTERS:
        return MICAM_READBACK, Guess.CLOCK_PERIOD
    if address in _SCAN_REGISTERS:
        return MICAM_READBACK, Guess.SCAN_REGISTERS
    return dev.phase, dev.phase


def _message(dev: DeviceState, tr: Transfer) -> Event:
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


# -- control transfers ------------------------------------------------------------------------


def _product_from_name(info: DeviceInfo, name: str) -> None:
    """micam names a device by its USB location until identified: "0867:3698 at bus 1 ..."."""
    vid, sep, rest = name.partition(":")
    if sep and vid == "0867" and len(rest) >= 4:
        try:
            info.product_id = int(rest[:4], 16)
        except ValueError:
            pass
