"""The USB driver through pyusb and the emulated backend: discovery, firmware, scans, trace."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from daq import (
    Board,
    BoardStateError,
    ClockSource,
    ConfigurationError,
    InputChannel,
    OutputChannel,
    ScanConfig,
    SyncGroup,
    TriggerSource,
)
from daq.usb import (
    FirmwareError,
    TransferTrace,
    UsbBoard,
    list_boards,
    open_boards,
    selftest,
)
from sim.usb import EmulatedBus, LoopbackBench, emulated_boards, synthetic_firmware
from sim.usb._clock import SharedClock

from .usb_helpers import BOARDS, RATE, burst, loop_bench, scan_configs


@pytest.fixture
def firmware(tmp_path: Path) -> Path:
    return synthetic_firmware(tmp_path / "firmware")


def test_list_boards_reports_loader_and_running_boards() -> None:
    bench = LoopbackBench()
    loader = EmulatedBus(bench, [("DT9836-6-2", "7")], firmware_loaded=False)
    running = EmulatedBus(bench, BOARDS, firmware_loaded=True)
    [info] = list_boards(loader.backend)
    assert (info.family, info.usb_id, info.firmware_loaded, info.model) == (
        "DT9836", "0867:9836", False, None)
    infos = list_boards(running.backend)
    assert [(i.model, i.serial, i.usb_id) for i in infos] == [
        ("DT9836-12-2", "1001", "0867:3698"), ("DT9836-12-2", "1002", "0867:3698"),
        ("DT9816-A", "1003", "0867:1698")]
    assert all(i.error is None and i.location.startswith("bus 1 port ") for i in infos)


def test_firmware_download_re_enumerates_every_board(firmware: Path) -> None:
    bus = EmulatedBus(loop_bench(), BOARDS, firmware_loaded=False)
    assert [b.descriptor.idProduct for b in bus.boards] == [0x9836, 0x9836, 0x9816]
    boards = open_boards(["1003", "1001"], backend=bus.backend, firmware_dir=firmware)
    try:
        assert [str(b.identity) for b in boards] == ["DT9816-A serial 1003",
                                                     "DT9836-12-2 serial 1001"]
        assert [b.descriptor.idProduct for b in bus.boards] == [0x3698, 0x3698, 0x1698]
        assert all(b.generation == 1 for b in bus.boards)  # each re-enumerated once
    finally:
        for b in boards:
            b.close()


def test_firmware_needs_a_directory_and_the_right_image(tmp_path: Path,
                                                        firmware: Path) -> None:
    bus = EmulatedBus(LoopbackBench(), [("DT9836-12-2", "5")], firmware_loaded=False)
    with pytest.raises(FirmwareError, match="no firmware directory"):
        open_boards(backend=bus.backend)
    with pytest.raises(FirmwareError, match="no firmware image 'a3load'"):
        open_boards(backend=bus.backend, firmware_dir=tmp_path)
    wrong = tmp_path / "wrong"
    wrong.mkdir()
    (wrong / "a3load.hex").write_text((firmware / "a3load.hex").read_text())
    (wrong / "dt9836.hex").write_text((firmware / "dt9816.hex").read_text())
    with pytest.raises(FirmwareError, match=r"0867:9836 at bus 1 port 1 did not re-enumerate"):
        open_boards(backend=bus.backend, firmware_dir=wrong, reenumerate_timeout_s=0.2)


def test_missing_serial_is_named() -> None:
    bus = EmulatedBus(LoopbackBench(), BOARDS)
    with pytest.raises(ConfigurationError, match=r"serial.*4242 not found.*DT9816-A serial 1003"):
        open_boards(["1001", "4242"], backend=bus.backend)


def test_synchronized_scan_with_outputs_seen_in_inputs() -> None:
    boards = emulated_boards(loop_bench(), BOARDS)
    assert all(isinstance(b, Board) and isinstance(b, UsbBoard) for b in boards)
    group = SyncGroup(boards)
    n = 20_000
    group.configure(scan_configs(n))
    wave = burst()
    rec = group.acquire({0: wave}, block_samples=4096)
    assert rec.codes.shape == (n, 12 + 12 + 6)
    c = rec.codes
    # master output 0 -> DT9816-A input 2 and output 1 -> second DT9836 input 11, from sample 0
    assert np.array_equal(c[: len(wave), 24 + 2], wave[:, 0])
    assert np.array_equal(c[: len(wave), 12 + 11], wave[:, 1])
    assert not c[len(wave):, 24 + 2].any()  # the outputs return to 0 V after the burst
    for col, (serial, ch) in {0: ("1001", 0), 13: ("1002", 1), 29: ("1003", 5)}.items():
        assert np.array_equal(c[:, col], LoopbackBench.ramp(serial, ch, 1, 0, n))
    # a second acquisition is scan 2 and needs its own burst
    rec2 = group.acquire(block_samples=5000)
    assert np.array_equal(rec2.codes[:, 0], LoopbackBench.ramp("1001", 0, 2, 0, n))
    assert not rec2.codes[:, 24 + 2].any()
    group.close()


def test_channel_order_and_range_follow_the_scan_config() -> None:
    bench = LoopbackBench({("1", 1): ("1", 3)})
    [board] = emulated_boards(bench, [("DT9836-6-2", "1")])
    assert isinstance(board, UsbBoard)
    config = ScanConfig(inputs=(InputChannel(channel=5, range_v=2.0),
                                InputChannel(channel=3, range_v=2.0),
                                InputChannel(channel=0, range_v=2.0)),
                        outputs=(OutputChannel(channel=1),), sample_rate_hz=RATE,
                        samples_per_channel=1000)
    board.configure(config)
    board.write(np.full((500, 1), 1000, np.int16))
    board.arm()
    board.start()
    block = board.read(1000, timeout_s=2.0)
    board.stop()
    board.close()
    assert block.start_index == 0 and block.board == board.identity
    assert np.array_equal(block.codes[:, 0], LoopbackBench.ramp("1", 5, 1, 0, 1000))
    assert np.array_equal(block.codes[:, 2], LoopbackBench.ramp("1", 0, 1, 0, 1000))
    # the looped output at ±10 V reads five times larger on the ±2 V input
    assert (block.codes[:500, 1] == 5000).all() and not block.codes[500:, 1].any()


def test_configuration_errors_name_the_board() -> None:
    [board] = emulated_boards(LoopbackBench(), [("DT9836-12-2", "77")])
    mixed = ScanConfig(inputs=(InputChannel(channel=0, range_v=10.0),
                               InputChannel(channel=1, range_v=2.0)), sample_rate_hz=RATE)
    with pytest.raises(ConfigurationError, match=r"DT9836-12-2 serial 77.*share one range"):
        board.configure(mixed)
    odd_rate = ScanConfig(inputs=(InputChannel(channel=0),), sample_rate_hz=96_001.0)
    with pytest.raises(ConfigurationError, match=r"DT9836-12-2 serial 77.*not 36 MHz"):
        board.configure(odd_rate)
    external = odd_rate.model_copy(update={"clock": ClockSource.EXTERNAL,
                                           "trigger": TriggerSource.EXTERNAL})
    board.configure(external)  # on the external clock the divider does not matter
    with pytest.raises(BoardStateError, match="serial 77: cannot read while configured"):
        board.read(10, 1.0)
    board.close()


def test_continuous_scan_streams_until_stopped() -> None:
    [board] = emulated_boards(LoopbackBench(), [("DT9816-A", "9")])
    board.configure(ScanConfig(inputs=(InputChannel(channel=4),), sample_rate_hz=RATE))
    board.arm()
    board.start()
    first = board.read(50_000, 2.0)
    second = board.read(1234, 2.0)
    board.stop()
    assert second.start_index == 50_000
    assert np.array_equal(np.concatenate([first.codes, second.codes])[:, 0],
                          LoopbackBench.ramp("9", 4, 1, 0, 51_234))
    board.close()


def test_realtime_clock_makes_samples_at_the_rate_of_its_time_source() -> None:
    """A real-time clock has made rate x elapsed edges since its trigger (a fake time source
    here: no test measures wall time), none for an older scan, and says how long edges take."""
    fake = [100.0]
    clock = SharedClock(LoopbackBench(), realtime=True, now=lambda: fake[0])
    scan = clock.fire(RATE)
    assert clock.edges(scan) == 0.0
    fake[0] += 0.05
    assert clock.edges(scan) == pytest.approx(0.05 * RATE)
    assert clock.edges(scan - 1) == 0.0
    assert clock.seconds_for(RATE) == pytest.approx(1.0)
    assert SharedClock(LoopbackBench(), realtime=False).edges(scan) == float("inf")


def test_realtime_clock_delivers_the_whole_scan() -> None:
    """Paced in wall time, the samples still arrive complete and in order."""
    bus = EmulatedBus(LoopbackBench(), [("DT9816-A", "4")], realtime=True)
    [board] = open_boards(backend=bus.backend)
    board.configure(ScanConfig(inputs=(InputChannel(channel=0),), sample_rate_hz=RATE,
                               samples_per_channel=9600))
    board.arm()
    board.start()
    block = board.read(9600, timeout_s=2.0)
    board.close()
    assert np.array_equal(block.codes[:, 0], LoopbackBench.ramp("4", 0, 1, 0, 9600))


def test_transfer_trace_records_every_transfer(tmp_path: Path, firmware: Path) -> None:
    path = tmp_path / "trace.jsonl"
    with TransferTrace(path) as trace:
        [board] = emulated_boards(LoopbackBench(), [("DT9836-12-2", "3")],
                                  firmware_dir=firmware, trace=trace)
        board.configure(scan_configs(100, [("DT9836-12-2", "3")], outputs_on_first=False)[0])
        board.arm()
        board.start()
        board.read(100, 2.0)
        board.stop()
        board.close()
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert {"t", "wall", "dev", "kind", "dir", "len", "status"} <= set(lines[0])
    assert lines[0]["kind"] == "ctrl" and lines[0]["request"] == 0xA0  # CPUCS reset first
    assert any(e.get("request") == 0xA3 for e in lines)
    commands = [e for e in lines if e.get("ep") == 0x01]
    assert commands[0]["data"].startswith("14000000")  # R_SINGLE_WORD_LB of VERSION_ID
    assert commands[0]["dev"] == "0867:3698 at bus 1 port 1"
    assert commands[-1]["dev"] == "DT9836-12-2 serial 3"
    streamed = sum(e["len"] for e in lines if e.get("ep") == 0x82 and e["status"] == "ok")
    assert streamed == 100 * 12 * 2
    assert all(b["t"] >= a["t"] for a, b in itertools.pairwise(lines))


def test_selftest_reports_rate_and_levels() -> None:
    [board] = emulated_boards(LoopbackBench(), [("DT9816", "12")])
    report = selftest(board, seconds=0.2)
    board.close()
    assert report.ok and report.board == "DT9816 serial 12"
    assert report.rate_hz == 50_000.0 and report.received == 10_000
    assert len(report.channels) == 6 and report.channels[0].max_code > report.channels[0].min_code
