"""The wire protocol: every implemented command, reply and message round-trips through bytes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from daq import ConfigurationError
from daq.usb import FirmwareError, ProtocolError, load_image, write_ihex
from daq.usb._protocol import (
    COMMANDS,
    AsyncMessage,
    CommandCode,
    MessageType,
    ReadI2cBytes,
    ReadWord,
    ReadWords,
    StartSubsystem,
    StopSubsystem,
    Subsystem,
    WriteWord,
    WriteWords,
    decode_command,
)
from daq.usb._unpublished import ScanSettings, clock_period, decode_stream, encode_stream

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)

COMMAND_STRATEGIES = {
    ReadI2cBytes: st.builds(ReadI2cBytes, st.lists(st.tuples(u8, u8), min_size=1,
                                                   max_size=29).map(tuple)),
    ReadWord: st.builds(ReadWord, u16),
    WriteWord: st.builds(WriteWord, u16, u16),
    ReadWords: st.builds(ReadWords, st.lists(u16, min_size=1, max_size=29).map(tuple)),
    WriteWords: st.builds(WriteWords, st.lists(st.tuples(u16, u16), min_size=1,
                                               max_size=14).map(tuple)),
    StartSubsystem: st.builds(StartSubsystem, st.sampled_from(Subsystem), u16),
    StopSubsystem: st.builds(StopSubsystem, st.sampled_from(Subsystem), u16),
}
READS = (ReadI2cBytes, ReadWord, ReadWords)


def test_every_implemented_command_has_a_strategy() -> None:
    assert set(COMMAND_STRATEGIES) == set(COMMANDS.values())


@given(st.one_of(*COMMAND_STRATEGIES.values()))
def test_command_packets_round_trip(command: object) -> None:
    packet = command.encode()  # type: ignore[attr-defined]
    assert len(packet) == 64
    assert packet[0] == command.code and packet[1:4] == b"\0\0\0"  # type: ignore[attr-defined]
    assert decode_command(packet) == command


@given(st.one_of(*(COMMAND_STRATEGIES[c] for c in READS)), st.data())
def test_replies_round_trip(command: object, data: st.DataObject) -> None:
    n = command.reply_length()  # type: ignore[attr-defined]
    values = data.draw(st.lists(u8 if isinstance(command, ReadI2cBytes) else u16,
                                min_size=n // (1 if isinstance(command, ReadI2cBytes) else 2),
                                max_size=n // (1 if isinstance(command, ReadI2cBytes) else 2)))
    reply = command.encode_reply(values)  # type: ignore[attr-defined]
    assert len(reply) == n
    assert command.decode_reply(reply) == tuple(values)  # type: ignore[attr-defined]


@given(st.builds(AsyncMessage, st.sampled_from(MessageType), u8))
def test_async_messages_round_trip(message: AsyncMessage) -> None:
    assert AsyncMessage.decode(message.encode()) == message


def test_byte_order_is_defined_per_command() -> None:
    """Local-bus words are big-endian (the FX2); SUBSYSTEM_INFO.ExtTrig is little-endian."""
    assert ReadWord(0x0020).encode()[4:6] == b"\x00\x20"
    assert WriteWords(((0x0005, 0xF800),)).encode()[4:9] == b"\x01\x00\x05\xf8\x00"
    assert ReadWords((0x0001, 0x0203)).encode()[4:9] == b"\x02\x00\x01\x02\x03"
    assert StartSubsystem(Subsystem.DA, 0x0001).encode()[4:10] == b"\x01\x00\x00\x00\x01\x00"
    assert ReadWord(0).decode_reply(b"\x12\x34") == (0x1234,)


def test_bad_packets_and_replies_are_protocol_errors() -> None:
    with pytest.raises(ProtocolError, match="64 bytes"):
        decode_command(b"\x14" * 10)
    with pytest.raises(ProtocolError, match="not implemented"):
        decode_command(bytes([CommandCode.W_DAC_THRESHOLD]) + bytes(63))
    with pytest.raises(ProtocolError, match=r"R_MULTI_WORD_LB.*3 bytes where 4"):
        ReadWords((1, 2)).decode_reply(b"\0\0\0")
    with pytest.raises(ProtocolError, match="unknown async message"):
        AsyncMessage.decode(b"\x63\0\0\0\0")
    with pytest.raises(ValueError, match=r"1\.\.14"):
        WriteWords(tuple((i, i) for i in range(15)))


settings_strategy = st.builds(
    ScanSettings,
    inputs=st.lists(st.integers(0, 11), min_size=1, unique=True).map(lambda v: tuple(sorted(v))),
    two_volt_range=st.booleans(),
    outputs=st.lists(st.integers(0, 3), unique=True).map(lambda v: tuple(sorted(v))),
    external_clock=st.booleans(),
    external_trigger=st.booleans(),
    samples=st.integers(0, 2**32 - 1),
    clock_period=st.integers(1, 2**32 - 1),
)


@given(settings_strategy)
def test_scan_settings_round_trip_through_registers(settings: ScanSettings) -> None:
    registers = dict(settings.registers())
    assert ScanSettings.from_registers(lambda a: registers.get(a, 0)) == settings


@given(arrays(np.int16, st.tuples(st.integers(0, 50), st.integers(1, 12))))
def test_stream_frames_round_trip(codes: np.ndarray) -> None:
    assert np.array_equal(decode_stream(encode_stream(codes), codes.shape[1]), codes)


def test_clock_period_accepts_only_exact_rates() -> None:
    assert clock_period(96_000.0, "b") == 375
    with pytest.raises(ConfigurationError, match="nearest"):
        clock_period(96_001.0, "DT9836-12-2 serial 1")


@given(st.lists(st.tuples(st.integers(0, 0xFF00), st.binary(min_size=1, max_size=64)),
                min_size=1, max_size=8))
def test_intel_hex_round_trip(tmp_path_factory: pytest.TempPathFactory,
                              segments: list[tuple[int, bytes]]) -> None:
    path = tmp_path_factory.mktemp("hex") / "img.hex"
    write_ihex(path, segments)
    image = load_image(path.parent, "img")
    flat = {a + i: b for a, d in segments for i, b in enumerate(d)}
    read = {a + i: b for a, d in image.segments for i, b in enumerate(d)}
    assert read == flat
    assert all(a <= 0x3FFF for a, _ in image.internal())
    assert all(a > 0x3FFF for a, _ in image.external())


def test_ihex2fw_binary_images_are_read(tmp_path: Path) -> None:
    """The Linux /lib/firmware format: BE u32 address, BE u16 length, data, pad to 4."""
    records = b"\x00\x00\x00\x10\x00\x03abc\x00\x00\x00" + b"\x00\x00\x50\x00\x00\x02xy" + bytes(6)
    (tmp_path / "dt9836.fw").write_bytes(records)
    image = load_image(tmp_path, "dt9836")
    assert image.segments == ((0x10, b"abc"), (0x5000, b"xy"))


def test_firmware_errors_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(FirmwareError, match=r"a3load\.hex, a3load\.ihx, a3load\.fw"):
        load_image(tmp_path, "a3load")
    (tmp_path / "bad.hex").write_text(":0300000002010AEE\n")
    with pytest.raises(FirmwareError, match="checksum"):
        load_image(tmp_path, "bad")
