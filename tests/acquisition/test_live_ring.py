"""The live ring buffer: the newest samples with their stream indices, whatever the block
sizes, never more than its capacity; frames found by stream index and camera."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.live.ring import FrameRing, SampleRing, StampedFrame


def test_the_ring_holds_the_newest_samples_across_wraps() -> None:
    stream = np.arange(3 * 1000, dtype=np.int16).reshape(-1, 3)  # 1000 samples, 3 columns
    ring = SampleRing(3, 128)
    index = 0
    for size in [5, 100, 1, 127, 128, 300, 7, 2, 330]:  # any sizes, larger than it too
        ring.append(stream[index: index + size])
        index += size
        first, held = ring.latest(1000)
        assert ring.end == index and first == max(0, index - 128)
        np.testing.assert_array_equal(held, stream[first:index])
    first, held = ring.latest(10)
    assert first == index - 10
    np.testing.assert_array_equal(held, stream[index - 10: index])


def test_the_ring_refuses_blocks_of_another_width() -> None:
    with pytest.raises(ValueError, match="blocks must be"):
        SampleRing(3, 10).append(np.zeros((4, 2), dtype=np.int16))


def test_frames_are_found_by_stream_index() -> None:
    frames = FrameRing(3, 2**20)
    image = np.zeros((2, 2), dtype=np.uint8)
    for sample in (0, 100, 200, 300):
        frames.append(StampedFrame("cam0", sample, image))
    assert [f.sample for f in frames.between(0, 1000)] == [100, 200, 300]  # the oldest went
    assert [f.sample for f in frames.between(150, 300, "cam0")] == [200]
    assert frames.between(0, 1000, "cam1") == []


def test_the_frames_kept_are_bounded_in_bytes() -> None:
    frames = FrameRing(100, 3 * 2**20)
    image = np.zeros((1024, 1024), dtype=np.uint8)  # 1 MiB
    for sample in range(10):
        frames.append(StampedFrame("cam0", sample, image))
    assert [f.sample for f in frames.between(0, 10)] == [7, 8, 9] and frames.nbytes == 3 * 2**20
    frames.append(StampedFrame("cam0", 10, np.zeros((4096, 1024), dtype=np.uint8)))
    assert [f.sample for f in frames.between(0, 11)] == [10]  # the newest, even if larger
