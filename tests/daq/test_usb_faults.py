"""Every injected fault gives its defined error, naming the board, and never shorter data."""

from __future__ import annotations

import pytest

from daq import (
    DeviceDisconnectedError,
    OverrunError,
    SyncGroup,
    TriggerTimeoutError,
)
from daq.usb import ProtocolError, StalledEndpointError, list_boards, open_boards
from sim.usb import EmulatedBus, Fault, emulated_boards

from .usb_helpers import BOARDS, burst, loop_bench, scan_configs

N = 30_000


def _group(*faults: Fault) -> SyncGroup:
    group = SyncGroup(emulated_boards(loop_bench(), BOARDS, faults=faults))
    group.configure(scan_configs(N))
    return group


def _acquire_fails(group: SyncGroup, error: type[Exception], match: str) -> None:
    with pytest.raises(error, match=match):
        group.acquire({0: burst()}, block_samples=4096, timeout_s=1.0)


def test_unplug_mid_scan_names_board_and_sample_index() -> None:
    group = _group(Fault("unplug", "1002", at_sample=12_345))
    _acquire_fails(group, DeviceDisconnectedError,
                   r"DT9836-12-2 serial 1002 is gone from the USB bus.*sample index 12345")
    group.close()


def test_unplugged_board_is_no_longer_listed() -> None:
    bus = EmulatedBus(loop_bench(), BOARDS, faults=[Fault("unplug", "1003", at_sample=100)])
    group = SyncGroup(open_boards(["1001", "1002", "1003"], backend=bus.backend))
    group.configure(scan_configs(N))
    with pytest.raises(DeviceDisconnectedError, match="DT9816-A serial 1003"):
        group.acquire(block_samples=4096, timeout_s=1.0)
    group.close()
    assert [i.serial for i in list_boards(bus.backend)] == ["1001", "1002"]


def test_fifo_overflow_is_an_overrun_naming_the_board() -> None:
    group = _group(Fault("fifo_overflow", "1003", at_sample=20_000))
    _acquire_fails(group, OverrunError,
                   r"DT9816-A serial 1003: its input FIFO overflowed after the host had "
                   r"received \d+ samples")
    # the boards can scan again after the failed acquisition
    assert group.acquire({0: burst()}, block_samples=4096).codes.shape[0] == N
    group.close()


@pytest.mark.slow
def test_missing_trigger_times_out_naming_the_board() -> None:
    group = _group(Fault("missing_trigger", "1002"))
    _acquire_fails(group, TriggerTimeoutError,
                   r"DT9836-12-2 serial 1002 delivered no samples .* saw no trigger")
    group.close()


def test_stalled_endpoint_names_board_endpoint_and_sample_index() -> None:
    group = _group(Fault("stall", "1001", at_sample=8_000))
    _acquire_fails(group, StalledEndpointError,
                   r"DT9836-12-2 serial 1001 stalled the transfer \(read from endpoint 0x82\)"
                   r".*sample index 8000")
    # stop() cleared the halt: the next scan runs
    assert group.acquire({0: burst()}, block_samples=4096).codes.shape[0] == N
    group.close()


def test_corrupt_reply_is_a_protocol_error_naming_the_board() -> None:
    group = SyncGroup(emulated_boards(loop_bench(), BOARDS,
                                      faults=[Fault("corrupt_reply", "1003")]))
    with pytest.raises(ProtocolError,
                       match=r"DT9816-A serial 1003: the reply to R_MULTI_WORD_LB has 21 bytes "
                             r"where 22"):
        group.configure(scan_configs(N))
    group.close()
