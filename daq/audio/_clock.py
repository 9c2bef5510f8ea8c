"""Several interfaces on one word clock: one trigger, fixed sample offsets, drift detected.

Interfaces wired to one word clock sample on the same clock edges, but each PortAudio stream
counts its own frames from its own start. The master's `start` places its recording window
at a frame of its stream; `fire` places every follower's window at the same instant of the
shared clock: the master's frame plus the follower's offset, the difference between the two
streams' frame counters. The offset is measured once from the streams' callback times (the
frame a callback began at and when it ran) and then kept: on one word clock it cannot change,
and keeping it makes every recording of a session see the same offset, which the calibration
then fits as that interface's latency. It is measured again after an xrun of any of the
streams (frames were lost, the counters jumped).

On every trigger the offset is measured again and compared with the kept one: interfaces on
different clocks (a word-clock cable missing, an interface left on its internal clock, two
rates) drift apart, the measured offset walks away from the kept one, and beyond
`tolerance_frames` the trigger fails with a SyncError that says so and by how many parts per
million, instead of recordings whose delays grow along the session.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

from daq import SyncError

if TYPE_CHECKING:
    from ._board import AudioBoard
    from ._stream import DuplexStream

DRIFT_TOLERANCE_S = 0.002
"""Timing noise of the callbacks allowed on top of two callback periods, seconds."""


def frame_offset(master: DuplexStream, follower: DuplexStream) -> float:
    """The follower's frame counter minus the master's at the same instant, from their latest
    callbacks (fractional frames)."""
    now = time.monotonic()
    assert master.anchor is not None and follower.anchor is not None
    (fm, tm), (ff, tf) = master.anchor, follower.anchor
    return (ff + (now - tf) * follower.rate_hz) - (fm + (now - tm) * master.rate_hz)


class WordClock:
    """The shared clock and trigger of several `AudioBoard`s (module docstring)."""

    def __init__(self) -> None:
        self.boards: list[AudioBoard] = []
        self._offsets: dict[str, tuple[int, float, int]] = {}  # label -> (offset, since, faults)
        self._lock = threading.Lock()

    def join(self, board: AudioBoard) -> None:
        self.boards.append(board)

    def fire(self, master: AudioBoard, window_frame: int) -> None:
        """Place every other armed board's window at the instant of the master's frame
        `window_frame`; SyncError if a board's clock drifted from the master's."""
        ms = master.stream
        with self._lock:
            for board in self.boards:
                if board is master or not board.armed:
                    continue
                fs = board.stream
                fs.wait_running()
                ms.wait_running()
                offset = self._offset(master, board, ms, fs)
                board.place_window(window_frame + offset)

    def _offset(self, master: AudioBoard, board: AudioBoard, ms: DuplexStream,
                fs: DuplexStream) -> int:
        measured = frame_offset(ms, fs)
        faults = ms.fault_count + fs.fault_count
        key = str(board.identity.serial)
        kept = self._offsets.get(key)
        if kept is None or kept[2] != faults:
            self._offsets[key] = (round(measured), time.monotonic(), faults)
            return round(measured)
        offset, since, _ = kept
        tolerance = 2 * max(ms.max_block, fs.max_block) + DRIFT_TOLERANCE_S * ms.rate_hz
        drift = measured - offset
        if abs(drift) > tolerance:
            elapsed = max(time.monotonic() - since, 1e-9)
            ppm = drift / (elapsed * ms.rate_hz) * 1e6
            raise SyncError(
                f"{board.identity} and {master.identity} drift apart: {board.identity.serial} "
                f"{'gained' if drift > 0 else 'lost'} {abs(drift):.0f} samples on "
                f"{master.identity.serial} in {elapsed:.1f} s ({ppm:+.0f} ppm), so they are "
                "not on one word clock: wire the master's word-clock output to every other "
                "interface and set those to their external (word) clock, or record with one "
                "interface")
        return offset
