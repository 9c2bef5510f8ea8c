"""Every board implementation keeps the `daq.Board` call order (`daq.CallOrder`): the legal
order works twice over (a board is armed again after `stop`), each call out of order raises
`BoardStateError`, and every call after `close` raises `DeviceDisconnectedError`.

Run against the simulated board, the real USB driver on the emulated bus, and the audio board
on the JACK server's own interface ("system", no world client), the only case needing the
server (skipped with the install command when the audio stack is missing)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping

import numpy as np
import pytest

from daq import (
    Board,
    BoardStateError,
    DeviceDisconnectedError,
    InputChannel,
    OutputBoard,
    OutputChannel,
    ScanConfig,
)
from sim.analog_bench import AcousticBench
from sim.boards import SimulatedBoard
from sim.arrays import BoardSpec, sphere72
from sim.usb import emulated_boards
from sim.world import World
from tests.daq.usb_helpers import RATE, loop_bench

N = 256
"""Samples per scan: a short one, read whole."""


def scan(rate_hz: float) -> ScanConfig:
    return ScanConfig(inputs=(InputChannel(channel=0), InputChannel(channel=1)),
                      outputs=(OutputChannel(channel=0),), sample_rate_hz=rate_hz,
                      samples_per_channel=N)


def simulated() -> tuple[Board, ScanConfig]:
    return (SimulatedBoard(BoardSpec("DT9836-12-2", "36001"),
                           AcousticBench(World(layout=sphere72()))), scan(RATE))


def emulated_usb() -> tuple[Board, ScanConfig]:
    [board] = emulated_boards(loop_bench(), [("DT9836-12-2", "1001")])
    return board, scan(RATE)


@pytest.fixture(params=["simulated", "emulated USB",
                        pytest.param("audio", marks=pytest.mark.slow)])  # a JACK server, 3 s
def board(request: pytest.FixtureRequest) -> Iterator[tuple[Board, ScanConfig]]:
    """A fresh board of each implementation and a scan it can do; closed at the end."""
    made: Board
    if request.param == "audio":
        request.getfixturevalue("jack_server")
        from daq.audio import AudioBoard, find_device
        from sim.jack_server import RATE_HZ

        made, config = AudioBoard(find_device("system"), "A"), scan(RATE_HZ)
    else:
        made, config = simulated() if request.param == "simulated" else emulated_usb()
    with made:
        yield made, config


def refused(calls: Mapping[str, Callable[[], object]],
            error: type[Exception] = BoardStateError) -> None:
    """Each of `calls` raises `error` (its message naming the state the board is in)."""
    for name, call in calls.items():
        try:
            call()
        except error as exc:
            assert ("while" if error is BoardStateError else "closed") in str(exc)
        else:
            pytest.fail(f"{name} was not refused")


def test_call_order(board: tuple[Board, ScanConfig]) -> None:
    b, config = board
    assert isinstance(b, OutputBoard)
    codes = np.zeros((N, 1), np.int16)
    every = {"configure": lambda: b.configure(config), "write": lambda: b.write(codes),
             "arm": b.arm, "start": b.start, "read": lambda: b.read(N, 5.0)}
    only = lambda *names: {n: every[n] for n in names}  # noqa: E731
    refused(only("write", "arm", "start", "read"))
    b.stop()  # before a scan: nothing to stop
    for _ in range(2):
        b.configure(config)
        refused(only("start", "read"))
        b.write(codes)
        b.arm()
        refused(only("configure", "write", "arm"))
        b.start()
        refused(only("configure", "write", "arm", "start"))
        block = b.read(N, 5.0)
        assert block.codes.shape == (N, 2) and block.start_index == 0
        b.stop()
        refused(only("start", "read"))
    b.close()
    refused(every, DeviceDisconnectedError)
    b.close()  # twice is harmless
