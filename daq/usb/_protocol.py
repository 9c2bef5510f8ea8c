"""The wire protocol of the DT9836 firmware: command packets, replies, asynchronous messages.

Public facts (Data Translation's 2013 DT9836 Linux driver, `dt9836_driver_fw_if.h`; see
docs/usb-protocol.md): every command is one 64-byte packet on endpoint 0x01: byte 0 the command
code, bytes 1..3 zero, the command's fields from byte 4, unused bytes zero. Read commands answer
with one packet on endpoint 0x81. Byte order is defined per command: the local-bus (FPGA
register) commands carry big-endian u16 fields (the FX2 is big-endian); SUBSYSTEM_INFO carries
its ExtTrig flags little-endian (unswapped, as uldaq sends them to the sibling DT9837).

Only the commands the driver uses are implemented; each is a frozen dataclass with `encode`
(the 64-byte packet), a `decode` classmethod that inverts it, and, for read commands,
`reply_length`, `encode_reply` and `decode_reply`. The emulated device (sim.usb) parses the same
packets with `decode_command`, so both sides share one definition of the bytes.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, ClassVar, Protocol, Self

from ._errors import ProtocolError
from ._ids import COMMAND_PACKET_BYTES

_HEADER = 4
"""Command code plus three filler bytes."""


class CommandCode(IntEnum):
    """USB_FIRMWARE_CMD_CODE values (the full public table; see `COMMANDS` for those built)."""

    R_BYTE_USB_REG = 0
    W_BYTE_USB_REG = 1
    R_MULTI_BYTE_USB_REG = 2
    W_MULTI_BYTE_USB_REG = 3
    RMW_BYTE_USB_REG = 4
    RMW_MULTI_BYTE_USB_REG = 5
    R_BYTE_I2C_REG = 10
    W_BYTE_I2C_REG = 11
    R_MULTI_BYTE_I2C_REG = 12
    W_MULTI_BYTE_I2C_REG = 13
    R_SINGLE_WORD_LB = 20
    W_SINGLE_WORD_LB = 21
    R_MULTI_WORD_LB = 22
    W_MULTI_WORD_LB = 23
    RMW_SINGLE_WORD_LB = 24
    RMW_MULTI_WORD_LB = 25
    START_SUBSYSTEM = 30
    STOP_SUBSYSTEM = 31
    R_SINGLE_VALUE_CMD = 32
    W_SINGLE_VALUE_CMD = 33
    R_SINGLE_VALUES_CMD = 34
    W_DAC_THRESHOLD = 40
    W_DAC_FIFO_SIZE = 41
    W_ADC_FIFO_SIZE = 42
    W_INT_ON_CHANGE_MASK = 43
    START_8051_DEBUGGER = 44
    WRITE_CAL_POT = 50
    READ_CAL_POT = 51


class Subsystem(IntEnum):
    """SUBSYSTEM_INFO.SubsystemType."""

    AD = 0
    DA = 1
    DIN = 2
    DOUT = 3
    SRL = 4
    CT = 5


class MessageType(IntEnum):
    """USB_MSG.MsgType of the asynchronous messages on endpoint 0x88."""

    CTR_OVERFLOW = 1
    DIN_CHANGED = 2
    DAC_THRESHOLD_REACHED = 3
    ADC_OVER_SAMPLE = 4
    INPUT_FIFO_OVERFLOW = 5
    OUTPUT_FIFO_UNDERFLOW = 6
    DAC_OVER_SAMPLE = 7
    OUTPUT_DONE = 8


class Command(Protocol):
    """What every implemented command offers."""

    code: ClassVar[CommandCode]

    def encode(self) -> bytes: ...


class ReadCommand(Command, Protocol):
    """A command answered by one reply packet on endpoint 0x81."""

    def reply_length(self) -> int: ...

    def decode_reply(self, reply: bytes) -> tuple[int, ...]: ...

    def encode_reply(self, values: Sequence[int]) -> bytes: ...


def _packet(code: CommandCode, payload: bytes) -> bytes:
    if len(payload) > COMMAND_PACKET_BYTES - _HEADER:
        raise ValueError(f"{code.name}: payload of {len(payload)} bytes does not fit a packet")
    return bytes((code, 0, 0, 0)) + payload + bytes(COMMAND_PACKET_BYTES - _HEADER - len(payload))


def _u8(v: int, what: str) -> int:
    if not 0 <= v <= 0xFF:
        raise ValueError(f"{what} {v} does not fit in one byte")
    return v


def _u16(v: int, what: str) -> int:
    if not 0 <= v <= 0xFFFF:
        raise ValueError(f"{what} {v} does not fit in 16 bits")
    return v


def _count(n: int, limit: int, code: CommandCode) -> None:
    if not 1 <= n <= limit:
        raise ValueError(f"{code.name} carries 1..{limit} items, not {n}")


def _check_reply(code: CommandCode, reply: bytes, expected: int) -> None:
    if len(reply) != expected:
        raise ProtocolError(
            f"the reply to {code.name} has {len(reply)} bytes where {expected} were expected "
            "(a corrupt or misrouted reply)"
        )


@dataclass(frozen=True)
class ReadI2cBytes:
    """R_MULTI_BYTE_I2C_REG: read bytes from I2C devices (the board EEPROM).

    Fields: NumReads u8, then {DevAddress u8, Register u8} x NumReads (at most 29).
    Reply: one byte per read, in order.
    """

    reads: tuple[tuple[int, int], ...]
    code: ClassVar[CommandCode] = CommandCode.R_MULTI_BYTE_I2C_REG
    MAX: ClassVar[int] = 29

    def __post_init__(self) -> None:
        _count(len(self.reads), self.MAX, self.code)
        for dev, reg in self.reads:
            _u8(dev, "I2C device address")
            _u8(reg, "I2C register")

    def encode(self) -> bytes:
        body = bytes([len(self.reads)]) + b"".join(bytes(pair) for pair in self.reads)
        return _packet(self.code, body)

    @classmethod
    def decode(cls, packet: bytes) -> Self:
        n = packet[_HEADER]
        body = packet[_HEADER + 1: _HEADER + 1 + 2 * n]
        return cls(tuple((body[2 * i], body[2 * i + 1]) for i in range(len(body) // 2)))

    def reply_length(self) -> int:
        return len(self.reads)

    def encode_reply(self, values: Sequence[int]) -> bytes:
        return bytes(_u8(v, "I2C byte") for v in values)

    def decode_reply(self, reply: bytes) -> tuple[int, ...]:
        _check_reply(self.code, reply, self.reply_length())
        return tuple(reply)


@dataclass(frozen=True)
class ReadWord:
    """R_SINGLE_WORD_LB: read one FPGA register. Fields: Address u16 BE. Reply: u16 BE."""

    address: int
    code: ClassVar[CommandCode] = CommandCode.R_SINGLE_WORD_LB

    def __post_init__(self) -> None:
        _u16(self.address, "register address")

    def encode(self) -> bytes:
        return _packet(self.code, struct.pack(">H", self.address))

    @classmethod
    def decode(cls, packet: bytes) -> Self:
        return cls(*struct.unpack_from(">H", packet, _HEADER))

    def reply_length(self) -> int:
        return 2

    def encode_reply(self, values: Sequence[int]) -> bytes:
        return struct.pack(">H", _u16(values[0], "register value"))

    def decode_reply(self, reply: bytes) -> tuple[int, ...]:
        _check_reply(self.code, reply, 2)
        return struct.unpack(">H", reply)


@dataclass(frozen=True)
class WriteWord:
    """W_SINGLE_WORD_LB: write one FPGA register. Fields: Address u16 BE, DataVal u16 BE."""

    address: int
    value: int
    code: ClassVar[CommandCode] = CommandCode.W_SINGLE_WORD_LB

    def __post_init__(self) -> None:
        _u16(self.address, "register address")
        _u16(self.value, "register value")

    def encode(self) -> bytes:
        return _packet(self.code, struct.pack(">HH", self.address, self.value))

    @classmethod
    def decode(cls, packet: bytes) -> Self:
        return cls(*struct.unpack_from(">HH", packet, _HEADER))


@dataclass(frozen=True)
class ReadWords:
    """R_MULTI_WORD_LB: read several FPGA registers.

    Fields: NumReads u8, then Address u16 BE x NumReads (at most 29) from the odd offset 5.
    Reply: one u16 BE per address, in order.
    """

    addresses: tuple[int, ...]
    code: ClassVar[CommandCode] = CommandCode.R_MULTI_WORD_LB
    MAX: ClassVar[int] = 29

    def __post_init__(self) -> None:
        _count(len(self.addresses), self.MAX, self.code)
        for a in self.addresses:
            _u16(a, "register address")

    def encode(self) -> bytes:
        n = len(self.addresses)
        return _packet(self.code, struct.pack(f">B{n}H", n, *self.addresses))

    @classmethod
    def decode(cls, packet: bytes) -> Self:
        n = packet[_HEADER]
        return cls(struct.unpack_from(f">{n}H", packet, _HEADER + 1))

    def reply_length(self) -> int:
        return 2 * len(self.addresses)

    def encode_reply(self, values: Sequence[int]) -> bytes:
        return struct.pack(f">{len(values)}H", *(_u16(v, "register value") for v in values))

    def decode_reply(self, reply: bytes) -> tuple[int, ...]:
        _check_reply(self.code, reply, self.reply_length())
        return struct.unpack(f">{len(self.addresses)}H", reply)


@dataclass(frozen=True)
class WriteWords:
    """W_MULTI_WORD_LB: write several FPGA registers in order.

    Fields: NumWrites u8, then {Address u16 BE, DataVal u16 BE} x NumWrites (at most 14).
    """

    writes: tuple[tuple[int, int], ...]
    code: ClassVar[CommandCode] = CommandCode.W_MULTI_WORD_LB
    MAX: ClassVar[int] = 14

    def __post_init__(self) -> None:
        _count(len(self.writes), self.MAX, self.code)
        for a, v in self.writes:
            _u16(a, "register address")
            _u16(v, "register value")

    def encode(self) -> bytes:
        flat = [x for pair in self.writes for x in pair]
        return _packet(self.code, struct.pack(f">B{len(flat)}H", len(self.writes), *flat))

    @classmethod
    def decode(cls, packet: bytes) -> Self:
        n = packet[_HEADER]
        flat = struct.unpack_from(f">{2 * n}H", packet, _HEADER + 1)
        return cls(tuple(zip(flat[0::2], flat[1::2], strict=True)))


@dataclass(frozen=True)
class _SubsystemCommand:
    """SUBSYSTEM_INFO: SubsystemType u8, Filler[3], ExtTrig u16 little-endian (flags)."""

    subsystem: Subsystem
    ext_trig: int = 0
    code: ClassVar[CommandCode]

    def __post_init__(self) -> None:
        _u16(self.ext_trig, "ExtTrig flags")

    def encode(self) -> bytes:
        return _packet(self.code, struct.pack("<B3xH", self.subsystem, self.ext_trig))

    @classmethod
    def decode(cls, packet: bytes) -> Self:
        subsystem, ext_trig = struct.unpack_from("<B3xH", packet, _HEADER)
        try:
            return cls(Subsystem(subsystem), ext_trig)
        except ValueError:
            raise ProtocolError(f"{cls.code.name}: unknown subsystem {subsystem}") from None


@dataclass(frozen=True)
class StartSubsystem(_SubsystemCommand):
    """START_SUBSYSTEM: start a subsystem (the AD or DA stream)."""

    code: ClassVar[CommandCode] = CommandCode.START_SUBSYSTEM


@dataclass(frozen=True)
class StopSubsystem(_SubsystemCommand):
    """STOP_SUBSYSTEM: stop a subsystem."""

    code: ClassVar[CommandCode] = CommandCode.STOP_SUBSYSTEM


COMMANDS: dict[CommandCode, type[Any]] = {
    c.code: c
    for c in (ReadI2cBytes, ReadWord, WriteWord, ReadWords, WriteWords, StartSubsystem,
              StopSubsystem)
}
"""The implemented commands by code."""


def decode_command(packet: bytes) -> Command:
    """Parse a 64-byte command packet (the device side); ProtocolError if it is not one."""
    if len(packet) != COMMAND_PACKET_BYTES:
        raise ProtocolError(f"a command packet has {COMMAND_PACKET_BYTES} bytes, not {len(packet)}")
    try:
        cls = COMMANDS[CommandCode(packet[0])]
    except (ValueError, KeyError):
        raise ProtocolError(f"command code {packet[0]} is not implemented") from None
    try:
        return cls.decode(packet)
    except (ValueError, struct.error) as e:
        raise ProtocolError(f"malformed {cls.code.name} packet: {e}") from None


@dataclass(frozen=True)
class AsyncMessage:
    """USB_MSG on endpoint 0x88: MsgType u8, Filler[3], one value byte (counter or port)."""

    kind: MessageType
    value: int = 0
    LENGTH: ClassVar[int] = 5

    def __post_init__(self) -> None:
        _u8(self.value, "message value")

    def encode(self) -> bytes:
        return struct.pack("<B3xB", self.kind, self.value)

    @classmethod
    def decode(cls, data: bytes) -> Self:
        if len(data) < cls.LENGTH:
            raise ProtocolError(f"an async message has {cls.LENGTH} bytes, not {len(data)}")
        kind, value = struct.unpack_from("<B3xB", data)
        try:
            return cls(MessageType(kind), value)
        except ValueError:
            raise ProtocolError(f"unknown async message type {kind}") from None
