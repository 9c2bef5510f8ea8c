"""`micam daq trace`: usbmon and USBPcap captures and micam's own traces decode alike, a
capture made by hand decodes by name, and `diff` names the guess each difference contradicts.

One emulated run (firmware download, a DT9836 with outputs as master and a DT9816-A, one
synchronised scan) is recorded twice: by the driver's `TransferTrace` and by a recording pyusb
backend under the driver, whose transfers `usb_capture` writes as usbmon (both link types,
pcap and pcapng, either byte order) and USBPcap captures, byte by byte.
"""

from __future__ import annotations

import json
import struct
from collections import defaultdict
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import daq.usb._board
import sim.usb._firmware
from daq import SyncGroup
from daq.usb import TransferTrace, open_boards
from daq.usb._protocol import Subsystem
from daq.usb._unpublished import Guess, ScanSettings
from daq.usb.bringup import Event, decode, diff_traces, read_transfers
from micam.cli import main
from sim.usb import EmulatedBus, emulated_boards, synthetic_firmware

from .usb_capture import (
    RecordingBackend,
    usbmon_records,
    usbpcap_records,
    write_pcap,
    write_pcapng,
)
from .usb_helpers import burst, loop_bench, scan_configs

BOARDS = [("DT9836-12-2", "3"), ("DT9816-A", "4")]
N = 200
CAPTURES = {
    "usbmon-189.pcap": (write_pcap, 189, False, False),
    "usbmon-220.pcap": (write_pcap, 220, True, False),
    "usbmon-189.pcapng": (write_pcapng, 189, False, False),
    "usbmon-220.pcapng": (write_pcapng, 220, True, False),
    "usbmon-220-big-endian.pcap": (write_pcap, 220, True, True),
    "usbpcap.pcap": (write_pcap, 249, None, False),
    "usbpcap.pcapng": (write_pcapng, 249, None, False),
}
"""name: (file writer, link type, 64-byte usbmon header?, big-endian?)."""


@dataclass(frozen=True)
class Run:
    trace: Path
    captures: dict[str, Path]


def _scan(boards: list) -> None:  # type: ignore[type-arg]
    group = SyncGroup(boards)
    try:
        group.configure(scan_configs(N, BOARDS))
        group.acquire({0: burst(100)}, block_samples=N)
    finally:
        group.close()


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    tmp = tmp_path_factory.mktemp("traces")
    bus = EmulatedBus(loop_bench(), BOARDS, firmware_loaded=False)
    backend = RecordingBackend(bus)
    with TransferTrace(tmp / "micam.jsonl") as trace:
        boards = open_boards(["3", "4"], backend=backend,
                             firmware_dir=synthetic_firmware(tmp / "firmware"), trace=trace,
                             reenumerate_timeout_s=2.0)
        _scan(list(boards))
    captures = {}
    for name, (write, linktype, mmapped, big) in CAPTURES.items():
        records = (usbpcap_records(backend.transfers) if linktype == 249
                   else usbmon_records(backend.transfers, bool(mmapped), big))
        captures[name] = write(tmp / name, linktype, records, big)
    return Run(tmp / "micam.jsonl", captures)


def _by_device(events: Iterator[Event]) -> dict[str, list[tuple[str, str]]]:
    out: dict[str, list[tuple[str, str]]] = defaultdict(list)
    for e in events:
        if e.kind != "poll":
            out[e.device].append((e.kind, e.text))
    return dict(out)


def _transfers(path: Path) -> dict[tuple[str, int], list[tuple[object, ...]]]:
    out: dict[tuple[str, int], list[tuple[object, ...]]] = defaultdict(list)
    for t in read_transfers(path):
        out[(t.device, t.endpoint)].append((t.kind, t.setup, t.length, t.data, t.status))
    return dict(out)


@pytest.mark.parametrize("name", list(CAPTURES))
def test_a_capture_decodes_to_the_transfers_of_micams_own_trace(run: Run, name: str) -> None:
    assert _transfers(run.captures[name]) == _transfers(run.trace)
    assert _by_device(decode(read_transfers(run.captures[name]))) == \
        _by_device(decode(read_transfers(run.trace)))


def test_the_decoded_run_names_every_step(run: Run) -> None:
    events = _by_device(decode(read_transfers(run.captures["usbmon-220.pcapng"])))
    loader, master = events["1:2"], events["1:4"]
    texts = [t for _, t in loader]
    assert texts[0] == "fx2 CPUCS <- 1: the 8051 held in reset"
    assert any(t.startswith("fx2 0xA3 external RAM 0x5b94-0x5ba5: 18 bytes") for t in texts)
    master_text = "\n".join(t for _, t in master)
    assert "command R_SINGLE_WORD_LB VERSION_ID" not in master_text  # kinds are separate
    assert ("command", "R_SINGLE_WORD_LB VERSION_ID") in master
    assert ("reply", "reply VERSION_ID = 0x0004 (DT9836-12-2)") in master
    assert ("reply", "reply 03 00 00 00 (EEPROM serial 3)") in master
    assert "INPUT_CHAN_MASK_LO = 0x0fff" in master_text
    assert "IO_OP_CONTROL = 0x0120 (OUTPUT_ARM|INPUT_SCAN_ARM)" in master_text
    assert ("command", "START_SUBSYSTEM DA ExtTrig 0x0000") in master
    assert "stream out 0x06: 1 transfers, 400 bytes = 100 frames of 2 channels" in master_text
    assert (f"stream in 0x82: 1 transfers, {N * 24} bytes = {N} frames of 12 channels"
            in master_text)
    assert "first frame -32575 -31575" in master_text  # LoopbackBench's ramp, channel 0 and 1
    follower = "\n".join(t for _, t in events["1:5"])
    assert "START_SUBSYSTEM AD ExtTrig 0x0001" in follower  # external trigger


def test_a_hand_made_usbmon_capture_is_decoded_by_name(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """One R_SINGLE_WORD_LB of VERSION_ID answered 0x0004, written here byte by byte from
    the pcap file header and the kernel's 48-byte `struct usbmon_packet`."""
    pcap = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 189)  # LINKTYPE_USB_LINUX
    command = bytes([20, 0, 0, 0, 0x00, 0x20]) + bytes(58)  # code 20, address 0x0020 BE

    def usbmon(urb: int, kind: bytes, epnum: int, status: int, length: int,
               data: bytes) -> bytes:
        # id, type, xfer_type 3 (bulk), epnum, devnum 7, busnum 2, flag_setup '-',
        # flag_data (0: data present, '<'/'>' absent), ts_sec, ts_usec, status, length,
        # len_cap, setup[8]
        flag = 0 if data else ord("<")
        return struct.pack("<QcBBBHbbqiiII8s", urb, kind, 3, epnum, 7, 2, ord("-"), flag,
                           1_700_000_000, 250, status, length, len(data), bytes(8)) + data

    records = [usbmon(0x10, b"S", 0x01, -115, 64, command), usbmon(0x10, b"C", 0x01, 0, 64, b""),
               usbmon(0x20, b"S", 0x81, -115, 64, b""),
               usbmon(0x20, b"C", 0x81, 0, 2, b"\x00\x04")]
    for i, r in enumerate(records):
        pcap += struct.pack("<IIII", 1_700_000_000, 250 + i, len(r), len(r)) + r
    path = tmp_path / "by-hand.pcap"
    path.write_bytes(pcap)
    assert main(["daq", "trace", "show", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split(None, 2)[1:] == ["2:7", "command  R_SINGLE_WORD_LB VERSION_ID"]
    assert out[1].split(None, 2)[2] == "reply    reply VERSION_ID = 0x0004 (DT9836-12-2)"
    assert out[2].startswith("2 transfers, 2 events shown")


def test_diff_of_the_driver_against_itself_is_empty(run: Run,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    assert diff_traces(run.trace, run.captures["usbpcap.pcapng"]).differences == ()
    assert main(["daq", "trace", "diff", str(run.captures["usbmon-189.pcap"]),
                 str(run.trace)]) == 0
    out = capsys.readouterr().out
    assert "no differences" in out
    # a capture started after enumeration holds no device descriptor: no product id
    assert "board: 1:4 DT9836-12-2 serial 3  <->  1:4 0867:3698 DT9836-12-2 serial 3" in out
    assert main(["daq", "trace", "diff", str(run.trace), str(run.trace), "--serial", "99"]) == 2
    assert "has no board with serial 99 with commands" in capsys.readouterr().err


# -- injected differences: the emulated driver with one guess changed -------------------------

ONE = [("DT9836-12-2", "3")]


def _one_scan(path: Path, fails: type[Exception] | None = None) -> Path:
    with TransferTrace(path) as trace:
        [board] = emulated_boards(loop_bench(), ONE, trace=trace)
        group = SyncGroup([board])
        try:
            group.configure(scan_configs(N, ONE))
            if fails is None:
                group.acquire({0: burst(100)}, block_samples=N)
            else:
                with pytest.raises(fails):
                    group.acquire({0: burst(100)}, block_samples=N)
        finally:
            group.close()
    return path


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _one_scan(tmp_path_factory.mktemp("reference") / "a.jsonl")


def test_diff_names_a_different_register_value(reference: Path, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    guessed = ScanSettings.registers

    def offset_binary_dac(self: ScanSettings) -> tuple[tuple[int, int], ...]:
        return tuple((a, 0x0001 if a == 0x010 else v) for a, v in guessed(self))

    monkeypatch.setattr(ScanSettings, "registers", offset_binary_dac)
    result = diff_traces(reference, _one_scan(tmp_path / "b.jsonl"))
    found = [(d.kind, d.key, d.a, d.b, d.guesses) for d in result.differences]
    assert found == [("value", "write MISC_CTRLS", "0x0003", "0x0001", (Guess.SCAN_REGISTERS,)),
                     ("value", "read MISC_CTRLS", "0x0003", "0x0001", (Guess.SCAN_REGISTERS,))]
    assert result.summary() == {Guess.SCAN_REGISTERS: 2}


def test_diff_names_a_missing_command(reference: Path, tmp_path: Path,
                                      monkeypatch: pytest.MonkeyPatch,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    guessed = daq.usb._board.arm_commands

    def no_output_start(settings: ScanSettings) -> list:  # type: ignore[type-arg]
        return [c for c in guessed(settings) if getattr(c, "subsystem", None) != Subsystem.DA]

    monkeypatch.setattr(daq.usb._board, "arm_commands", no_output_start)
    b = _one_scan(tmp_path / "b.jsonl")
    [d] = diff_traces(reference, b).differences
    assert (d.kind, d.key, d.a, d.b, d.guesses) == (
        "missing", "START_SUBSYSTEM DA", "ExtTrig 0x0000", None, (Guess.ARM_COMMANDS,))
    assert main(["daq", "trace", "diff", str(reference), str(b)]) == 1
    out = capsys.readouterr().out
    assert "first difference: [1:2 0867:3698 DT9836-12-2 serial 3 | 1:2 0867:3698 " \
           "DT9836-12-2 serial 3] missing in B: START_SUBSYSTEM DA = ExtTrig 0x0000" in out
    assert "contradicts daq/usb/_unpublished.py: arm_commands" in out
    assert "summary: 1 differences; arm_commands: 1" in out


def test_diff_names_a_changed_stream_framing(reference: Path, tmp_path: Path,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """A board that sends a status word after each frame: the driver reads torn frames."""
    guessed = sim.usb._firmware.encode_stream

    def with_status_word(codes: np.ndarray) -> bytes:
        return guessed(np.hstack([codes, np.full((len(codes), 1), 0x7E7E, np.int16)]))

    monkeypatch.setattr(sim.usb._firmware, "encode_stream", with_status_word)
    b = _one_scan(tmp_path / "b.jsonl", fails=daq.usb.ProtocolError)
    [d] = diff_traces(reference, b).differences
    assert (d.kind, d.key, d.guesses) == ("value", "stream in 0x82", (Guess.STREAM_DTYPE,))
    assert d.a == "12-channel frames, whole, as many frames as the scan's samples"
    assert d.b == "12-channel frames, torn, more frames than the scan's samples"


def test_every_guess_identity_names_an_entry_of_unpublished() -> None:
    import daq.usb._unpublished as unpublished

    for guess in Guess:
        obj: object = unpublished
        for part in guess.value.split("."):
            obj = getattr(obj, part)


def test_show_selects_by_device_serial_and_time_and_prints_pure_json(
        run: Run, capsys: pytest.CaptureFixture[str]) -> None:
    capture = str(run.captures["usbmon-220.pcap"])
    assert main(["daq", "trace", "show", capture, "--json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert {e["device"] for e in lines} == {"1:2", "1:3", "1:4", "1:5"}
    assert all(e["kind"] != "poll" for e in lines)
    version = next(e for e in lines if e["kind"] == "reply" and e["device"] == "1:5")
    assert version["values"] == [{"register": "VERSION_ID", "value": 0x4816}]
    stream = next(e for e in lines if e["kind"] == "stream" and e["endpoint"] == 0x82)
    assert (stream["frames"], stream["torn_bytes"], len(stream["first_frame"])) == (N, 0, 12)

    assert main(["daq", "trace", "show", capture, "--serial", "4", "--json"]) == 0
    serial4 = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert {e["device"] for e in serial4} == {"1:5"}
    assert serial4[0]["command"] == "R_SINGLE_WORD_LB"  # held until the serial showed
    assert main(["daq", "trace", "show", capture, "--device", "1:2", "--json"]) == 0
    assert {json.loads(x)["kind"] for x in capsys.readouterr().out.splitlines()} == {"firmware"}

    t = [e["t"] for e in lines]
    start, end = t[len(t) // 3], t[2 * len(t) // 3]
    assert main(["daq", "trace", "show", capture, "--from", str(start), "--to", str(end),
                 "--json", "--polls"]) == 0
    window = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert window and all(start <= e["t"] <= end for e in window)
    assert main(["daq", "trace", "show", capture, "--polls"]) == 0
    assert " poll     bulk in 0x88: nothing (cancelled)" in capsys.readouterr().out


def test_a_record_of_a_real_wireshark_usbmon_capture_reads_as_wireshark_shows_it(
        tmp_path: Path) -> None:
    """The 64-byte header of a GET_DESCRIPTOR submission as Wireshark captured it on usbmon2
    (a public capture: Wireshark shows URB id 0xffff880151d719c0, 'S', control, endpoint 0x80,
    device 40, bus 2, setup 80 06 00 01 00 00 12 00, -EINPROGRESS, length 18)."""
    record = bytes.fromhex(
        "c019d7510188ffff 53 02 80 28 0200 00 3c"  # id, 'S', control, 0x80, 40, bus 2, 0, '<'
        "9a48865800000000 d9340800 8dffffff"  # ts_sec, ts_usec, status -115
        "12000000 00000000 8006000100001200"  # length 18, len_cap 0, setup
        "00000000 00000000 00020000 00000000")  # interval, start_frame, xfer_flags, ndesc
    assert len(record) == 64
    path = write_pcap(tmp_path / "wireshark.pcap", 220, [(1485195418.537817, record)])
    [t] = list(read_transfers(path))
    assert (t.device, t.kind, t.endpoint, t.status) == ("2:40", "ctrl", 0x80, "incomplete")
    assert t.setup is not None and (t.setup.request_type, t.setup.request, t.setup.value,
                                    t.setup.length) == (0x80, 6, 0x0100, 18)
    [event] = list(decode([t]))
    assert event.text.startswith("GET_DESCRIPTOR value 0x0100 index 0x0000")
