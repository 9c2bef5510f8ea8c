"""`micam daq probe` on the emulated bus: ids, descriptors, VERSION_ID and EEPROM, read
without one transfer that could change a board (every transfer is recorded under the driver),
and a report and a trace written for a bug report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import usb.core

from daq.usb._protocol import ReadI2cBytes, ReadWord, WriteWords, decode_command
from daq.usb._transport import UsbTransport
from daq.usb.bringup import ReadOnlyChannel, WriteRefusedError, probe, read_transfers
from micam.cli import main
from sim.usb import EmulatedBus, LoopbackBench

from .usb_capture import RecordingBackend

BOARDS = [("DT9836-12-2", "1001"), ("DT9816-A", "1003")]


def _state(bus: EmulatedBus) -> list[object]:
    return [(dict(b.firmware.registers), bytes(b.firmware.eeprom), b.firmware._scan,
             b.firmware._input_armed, b.firmware._output_armed, b.generation)
            for b in bus.boards if b.firmware is not None]


def test_the_probe_reads_ids_version_and_eeprom_and_writes_nothing() -> None:
    bus = EmulatedBus(LoopbackBench(), BOARDS)
    backend = RecordingBackend(bus)
    before = _state(bus)
    report = probe(backend)
    assert [(b.usb_id, b.family, b.firmware_running, b.version_id, b.model, b.serial)
            for b in report.boards] == [
        ("0867:3698", "DT9836", True, 0x0004, "DT9836-12-2", "1001"),
        ("0867:1698", "DT9816", True, 0x4816, "DT9816-A", "1003")]
    assert report.boards[0].eeprom == "c0670898360000" + "00" + "e9030000" + "00" * 4  # 1001 LE
    assert report.boards[0].eeprom_ids == "0867:3698"
    assert {e.address for e in report.boards[0].endpoints} == {0x88, 0x01, 0x81, 0x06, 0x82,
                                                               0x04}
    assert all(b.findings == [] and b.error is None for b in report.boards)
    # what went over the bus: read commands on 0x01 and their replies, nothing else
    assert _state(bus) == before
    assert all(t.kind == "bulk" for t in backend.transfers)  # no control transfer at all
    sent = [decode_command(t.out) for t in backend.transfers if not t.endpoint & 0x80]
    assert all(t.endpoint == 0x01 for t in backend.transfers if not t.endpoint & 0x80)
    assert [type(c) for c in sent] == [ReadWord, ReadI2cBytes] * 2
    assert {t.endpoint for t in backend.transfers} == {0x01, 0x81}


def test_a_board_without_firmware_is_described_without_a_transfer() -> None:
    bus = EmulatedBus(LoopbackBench(), [("DT9836-6-2", "7")], firmware_loaded=False)
    backend = RecordingBackend(bus)
    [board] = probe(backend).boards
    assert (board.usb_id, board.firmware_running, board.endpoints, board.version_id) == (
        "0867:9836", False, [], None)
    assert backend.transfers == []
    assert bus.boards[0].boot is not None and not bus.boards[0].boot.loader_running


def test_an_unknown_running_id_points_at_the_dt9816_guess() -> None:
    bus = EmulatedBus(LoopbackBench(), [("DT9816", "9")])
    bus.boards[0].descriptor.idProduct = 0x1699  # a DT9816 whose running id is not the guess
    [board] = probe(bus.backend).boards
    assert board.family is None and board.model == "DT9816" and board.serial == "9"
    [finding] = board.findings
    assert "set DT9816_RUNNING_PID = 0x1699 in daq/usb/_unpublished.py" in finding


def test_the_read_only_channel_refuses_a_write_before_the_wire() -> None:
    bus = EmulatedBus(LoopbackBench(), BOARDS[:1])
    backend = RecordingBackend(bus)
    dev = usb.core.find(backend=backend, idVendor=0x0867)
    transport = UsbTransport(dev)
    channel = ReadOnlyChannel(transport)
    with pytest.raises(WriteRefusedError, match="read commands only, not W_MULTI_WORD_LB"):
        channel.write_registers([(0x006, 0x0020)])
    with pytest.raises(WriteRefusedError):
        channel.send(WriteWords(((0x010, 3),)))
    assert channel.read_registers([0x020]) == (0x0004,)
    transport.close()
    assert len(backend.transfers) == 2  # the one read and its reply


def test_micam_daq_probe_writes_a_report_and_a_trace(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["daq", "probe", "--emulate", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "0867:3698 at bus 1 port 1" in out and "VERSION_ID 0x0004: DT9836-12-2" in out
    [report] = tmp_path.glob("micam-probe-*.json")
    [trace] = tmp_path.glob("micam-probe-*.trace.jsonl")
    boards = json.loads(report.read_text())["boards"]
    assert len(boards) == 10  # the simulated sphere's boards
    commands = [t for t in read_transfers(trace) if t.endpoint == 0x01]
    assert len(commands) == 20
    assert {type(decode_command(t.data)) for t in commands} == {ReadWord, ReadI2cBytes}
    assert main(["daq", "probe", "--emulate", "--out", str(tmp_path / "new" / "dir")]) == 0
    assert len(list((tmp_path / "new" / "dir").glob("micam-probe-*.json"))) == 1
    a_file = tmp_path / "a-file"
    a_file.write_text("")
    capsys.readouterr()
    assert main(["daq", "probe", "--emulate", "--out", str(a_file)]) == 2
    assert "is a file, not a directory" in capsys.readouterr().err


def test_probe_without_libusb_is_one_line_and_leaves_no_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    import daq.usb.bringup

    def no_backend(*args: object) -> None:
        raise usb.core.NoBackendError("No backend available")

    monkeypatch.setattr(daq.usb.bringup, "probe", no_backend)
    assert main(["daq", "probe", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot scan the USB bus" in err
    assert list(tmp_path.iterdir()) == []
