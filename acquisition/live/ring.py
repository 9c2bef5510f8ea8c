"""The latest seconds of a continuous scan, in a bounded buffer that never grows.

`SampleRing` keeps the newest `capacity` samples of every column (int16 codes, as the boards
deliver them) with their stream indices; older samples are overwritten. `FrameRing` keeps the
newest camera frames with the stream index at which each was taken, so that a recording or
a map finds the frame that matches a time of the scan; it holds at most a number of frames
and a number of bytes (frames are full-size images: 30 s at 30 fps of two 1280 x 960 colour
cameras would be 6.6 GB), dropping the oldest first.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


class SampleRing:
    """The newest `capacity` samples (n_columns int16 columns) of a stream."""

    def __init__(self, n_columns: int, capacity: int) -> None:
        if capacity < 1 or n_columns < 1:
            raise ValueError(f"a ring needs at least one sample and one column, got "
                             f"{capacity} x {n_columns}")
        self._data = np.zeros((capacity, n_columns), dtype=np.int16)
        self.capacity = int(capacity)
        self.end = 0  # stream index one past the newest sample

    @property
    def start(self) -> int:
        """Stream index of the oldest sample held."""
        return max(0, self.end - self.capacity)

    def append(self, codes: np.ndarray) -> None:
        """Append a block (n, n_columns) that follows the newest sample."""
        codes = np.asarray(codes)
        if codes.ndim != 2 or codes.shape[1] != self._data.shape[1]:
            raise ValueError(f"blocks must be (n, {self._data.shape[1]}), got {codes.shape}")
        keep = codes[-self.capacity:]  # only the newest `capacity` can be held
        first = (self.end + len(codes) - len(keep)) % self.capacity
        head = min(len(keep), self.capacity - first)
        self._data[first: first + head] = keep[:head]
        self._data[: len(keep) - head] = keep[head:]
        self.end += len(codes)

    def latest(self, n_samples: int) -> tuple[int, np.ndarray]:
        """(stream index of the first, a copy (n, n_columns)) of the newest n samples held
        (fewer when the ring holds fewer)."""
        n = min(int(n_samples), self.end - self.start)
        first = self.end - n
        rows = np.arange(first, self.end) % self.capacity
        return first, self._data[rows]


@dataclass(frozen=True)
class StampedFrame:
    """A camera frame taken when the scan had reached stream index `sample`."""

    camera: str
    sample: int
    image: np.ndarray


class FrameRing:
    """The newest camera frames (at most `capacity` frames of at most `max_bytes` in all, and
    always the newest one), oldest first."""

    def __init__(self, capacity: int, max_bytes: int) -> None:
        if capacity < 1:
            raise ValueError(f"a frame ring needs room for at least one frame, not {capacity}")
        self._frames: deque[StampedFrame] = deque()
        self.capacity = int(capacity)
        self.max_bytes = int(max_bytes)
        self.nbytes = 0

    def append(self, frame: StampedFrame) -> None:
        self._frames.append(frame)
        self.nbytes += frame.image.nbytes
        while len(self._frames) > 1 and (len(self._frames) > self.capacity
                                         or self.nbytes > self.max_bytes):
            self.nbytes -= self._frames.popleft().image.nbytes

    def between(self, start: int, end: int, camera: str | None = None) -> list[StampedFrame]:
        """The frames (of `camera`, or every camera) taken at stream indices [start, end)."""
        return [f for f in self._frames if start <= f.sample < end
                and (camera is None or f.camera == camera)]
