"""Several interfaces on one word clock: the world's interface (the master, playing the
burst) and the server's own dummy interface (a follower) record one aligned acquisition on a
real JACK server; interfaces whose clocks drift apart fail the trigger with the drift named."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest

from daq import InputChannel, OutputChannel, OverrunError, ScanConfig, SyncError, SyncGroup
from daq.audio import AudioConfig, AudioDeviceConfig, open_audio_boards
from daq.audio import _clock
from sim.jack_world import WorldProcess

from .jack_helpers import PERIOD, acquire_whole
from .test_audio_board import OPTIONS, burst_codes

pytestmark = pytest.mark.slow  # every test here: a JACK server and the world as its client

N = PERIOD + 4096


@pytest.fixture(scope="module")
def two(jack_server) -> Iterator[SyncGroup]:  # noqa: ANN001
    world = WorldProcess(OPTIONS.model_dump_json(), "micam-test-world-clock")
    config = AudioConfig(word_clock=True, devices=(AudioDeviceConfig(label="A", name=world.name),
                                                   AudioDeviceConfig(label="B", name="system")))
    group = SyncGroup(open_audio_boards(config, ["A", "B"]))
    group.configure([
        ScanConfig(inputs=tuple(InputChannel(channel=c) for c in range(16)),
                   outputs=(OutputChannel(channel=0),), sample_rate_hz=96_000,
                   samples_per_channel=N),
        ScanConfig(inputs=(InputChannel(channel=0), InputChannel(channel=1)),
                   sample_rate_hz=96_000, samples_per_channel=N)])
    yield group
    group.close()
    world.close()


def test_two_interfaces_on_one_word_clock_record_one_acquisition(two: SyncGroup) -> None:
    clock = two.boards[0]._clock  # type: ignore[attr-defined]
    first = acquire_whole(two, {0: burst_codes()})
    kept = dict(clock._offsets)
    second = acquire_whole(two, {0: burst_codes()})
    assert first.codes.shape == second.codes.shape == (N, 18)
    assert [c for c in first.columns] == [slice(0, 16), slice(16, 18)]
    assert np.abs(first.codes[:, :15]).max() > 100  # the world's microphones hear the burst
    for label, (offset, _, faults) in clock._offsets.items():  # kept, unless an xrun came
        assert offset == kept[label][0] or faults != kept[label][2]


def test_interfaces_that_drift_apart_fail_the_trigger(two: SyncGroup,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Measured offsets walking away from the kept one (as two free-running clocks do, here
    a follower 5 % fast) beyond the callbacks' timing noise: the trigger fails and says by how
    much. The measurement is what is shifted: one JACK server is one clock."""
    real = _clock.frame_offset
    t0 = time.monotonic()
    monkeypatch.setattr(_clock, "frame_offset",
                        lambda m, f: real(m, f) + 0.05 * 96_000 * (time.monotonic() - t0))
    with pytest.raises(SyncError, match=r'audio interface B \("system", .*\) and audio '
                                        r"interface A .* drift apart: B gained \d+ samples "
                                        r"on A in .* s \(\+\d+ ppm\), so they are not on one "
                                        r"word clock"):
        for _ in range(40):  # bounded: 5 % of drift passes the tolerance within a second
            try:
                two.acquire({0: burst_codes()})
            except OverrunError:  # an xrun of the loaded machine: measured again, go on
                continue
