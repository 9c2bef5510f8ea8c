"""Which set-up the simulated world is in, so that its noise is keyed by what is captured.

Real noise never repeats; simulated noise must, so that a capture resumed in a new process
(after a crash or a stop) records exactly what an uninterrupted capture with the same seed
records, and a test can compare results across the interruption. So every random draw of a
scan (the boards' input noise) and of a camera frame (the sensor noise) is keyed by the world's
seed, the set-up the operator made (which step: reference k, the reference microphone on its
stand, pose i) and the number of scans or frames taken since that set-up was made, never by
how many the process took before. An attempt captured again after a failure therefore records
the same noise as the first; frames grabbed while waiting (hands-free looks) count as frames.
"""

from __future__ import annotations

import threading
from collections import Counter

Key = tuple[int, ...]

REFERENCE_SETUP = 1
"""The first number of a set-up key: the reference microphone in front of speaker k, (1, k)."""
STAND_SETUP = 2
"""The reference microphone on its stand, the rig touching it (the refmic step): (2, 0)."""
POSE_SETUP = 3
"""The rig held at pose i: (3, i)."""


def reference_setup(speaker: int) -> Key:
    """The set-up key of speaker `speaker`'s reference recording."""
    return (REFERENCE_SETUP, speaker)


def pose_setup(pose: int) -> Key:
    """The set-up key of pose `pose`."""
    return (POSE_SETUP, pose)


class Setups:
    """The current set-up and the scans and frames taken in it (thread-safe: boards may
    trigger from a reader thread)."""

    def __init__(self) -> None:
        self._key: Key = (0, 0)  # before any set-up: what a bare bench or camera records
        self._scans = 0
        self._frames: Counter[int] = Counter()
        self._lock = threading.Lock()

    def begin(self, key: Key) -> None:
        """The operator made set-up `key`: counting starts again from zero."""
        with self._lock:
            self._key = key
            self._scans = 0
            self._frames.clear()

    def current(self) -> Key:
        """The current set-up's key (counting nothing)."""
        with self._lock:
            return self._key

    def next_scan(self) -> Key:
        """The key of the scan that starts now: (set-up..., scan number within it)."""
        with self._lock:
            n = self._scans
            self._scans += 1
            return (*self._key, n)

    def next_frame(self, camera: int) -> Key:
        """The key of the frame camera `camera` takes now: (set-up..., frame number)."""
        with self._lock:
            n = self._frames[camera]
            self._frames[camera] += 1
            return (*self._key, n)
