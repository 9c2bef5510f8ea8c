"""A sync group of simulated boards: aligned blocks, and every hardware failure named."""

from __future__ import annotations

import numpy as np
import pytest

from daq import (
    Block,
    BoardStateError,
    ConfigurationError,
    DeviceDisconnectedError,
    InputChannel,
    OutputChannel,
    OverrunError,
    ScanConfig,
    SyncError,
    SyncGroup,
    TriggerTimeoutError,
    volts_to_codes,
)
from sim.arrays import BoardSpec, sphere72
from sim.analog_bench import AcousticBench
from sim.boards import SimulatedBoard
from sim.world import NoiseModel, World

N = 6000


def _group(noise: float = 1.0) -> tuple[SyncGroup, list[SimulatedBoard], World]:
    world = World(layout=sphere72(), noise=NoiseModel(scale=noise), seed=5)
    bench = AcousticBench(world)
    boards = [SimulatedBoard(spec, bench) for spec in world.layout.boards]
    group = SyncGroup(boards)
    configs = []
    for spec in world.layout.boards:
        n_in = 12 if spec.model.startswith("DT9836") else 6
        outputs = (OutputChannel(channel=0), OutputChannel(channel=1)) if n_in == 12 else ()
        configs.append(ScanConfig(inputs=tuple(InputChannel(channel=c) for c in range(n_in)),
                                  outputs=outputs, sample_rate_hz=96_000.0,
                                  samples_per_channel=N))
    group.configure(configs)
    return group, boards, world


def _burst() -> np.ndarray:
    volts = np.zeros((2000, 2))
    volts[100:1100, 0] = np.random.default_rng(0).choice([-1.0, 1.0], 1000)
    return volts_to_codes(volts, 10.0)


def test_group_returns_aligned_recording_with_the_burst_everywhere() -> None:
    group, _, world = _group()
    rec = group.acquire({0: _burst()}, block_samples=1024)
    assert rec.codes.shape == (N, 3 * 12 + 6 * 6 + 6)
    assert [b.serial for b in rec.boards] == [b.serial for b in world.layout.boards]
    # speaker 0 (board 0, output 0) is heard on every microphone of every board
    quiet = rec.codes[:50].astype(float).std(axis=0)
    loud = rec.codes[200:1400].astype(float).std(axis=0)
    mic_columns = np.r_[0:72]
    assert np.all(loud[mic_columns] > 3 * quiet[mic_columns])


def test_same_samples_whatever_the_block_size() -> None:
    a, _, _ = _group()
    b, _, _ = _group()
    ra = a.acquire({0: _burst()}, block_samples=N)
    rb = b.acquire({0: _burst()}, block_samples=777)
    assert np.array_equal(ra.codes, rb.codes)


def test_unplugged_board_is_named_with_its_sample_index() -> None:
    group, boards, _ = _group()
    boards[4].faults.unplug_at_sample = 3000
    with pytest.raises(DeviceDisconnectedError, match=r"16002.*sample 3000"):
        group.acquire(block_samples=1000)


def test_overrun_is_an_error_not_shorter_data() -> None:
    group, boards, _ = _group()
    boards[1].faults.overrun_at_sample = 2500
    with pytest.raises(OverrunError, match=r"36002.*2500"):
        group.acquire(block_samples=1000)


def test_missing_trigger_times_out_naming_the_board() -> None:
    group, boards, _ = _group()
    boards[2].faults.miss_trigger = True
    with pytest.raises(TriggerTimeoutError, match="36003"):
        group.acquire(timeout_s=0.2)
    # the group recovers on the next acquisition
    assert group.acquire().codes.shape[0] == N


def test_misaligned_board_is_a_sync_error() -> None:
    group, boards, _ = _group()
    board = boards[3]
    original = board.read

    def skip_ahead(n_samples: int, timeout_s: float) -> Block:
        block = original(n_samples, timeout_s)
        return type(block)(block.codes, block.start_index + 1, block.board)

    board.read = skip_ahead  # type: ignore[method-assign]
    with pytest.raises(SyncError, match=r"16001.*expected 0\.\."):
        group.acquire()


def test_group_refuses_mixed_rates_and_duplicate_boards() -> None:
    world = World(layout=sphere72())
    bench = AcousticBench(world)
    a = SimulatedBoard(BoardSpec("DT9836-12-2", "36001"), bench)
    b = SimulatedBoard(BoardSpec("DT9816-A", "16001"), bench)
    with pytest.raises(ConfigurationError, match="listed twice"):
        SyncGroup([a, a])
    group = SyncGroup([a, b])
    with pytest.raises(ConfigurationError, match="one sample rate"):
        group.configure([
            ScanConfig(inputs=(InputChannel(channel=0),), sample_rate_hz=96_000.0,
                       samples_per_channel=10),
            ScanConfig(inputs=(InputChannel(channel=0),), sample_rate_hz=48_000.0,
                       samples_per_channel=10),
        ])


def test_calls_in_the_wrong_order_are_refused() -> None:
    world = World(layout=sphere72())
    board = SimulatedBoard(BoardSpec("DT9836-12-2", "36001"), AcousticBench(world))
    with pytest.raises(BoardStateError, match="needs configured"):
        board.arm()
    board.close()
    with pytest.raises(DeviceDisconnectedError):
        board.configure(ScanConfig(inputs=(InputChannel(channel=0),), sample_rate_hz=1000.0))
