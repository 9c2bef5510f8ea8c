"""A loopback bench: an `AnalogBench` with known input codes and cable-looped outputs.

For the driver's tests, the throughput benchmark and emulated self-tests, where the acoustic
world would only hide what the driver did: every input reads a ramp that names its board,
channel, scan and sample index (`LoopbackBench.ramp`), except inputs wired to an output, which
read that output's codes (rescaled to the input range) while the waveform plays and 0 after.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence

import numpy as np

from daq import CODE_FULL_SCALE, InputChannel

Jack = tuple[str, int]
"""(board serial, channel number)."""


class LoopbackBench:
    """Deterministic inputs, outputs looped back by cables; thread-safe.

    Args:
        wires: output jack -> input jack, e.g. {("1001", 0): ("1002", 5)}.
    """

    def __init__(self, wires: Mapping[Jack, Jack] | None = None) -> None:
        self.wires = dict(wires or {})
        self._cond = threading.Condition()
        self._scan = 0
        self._queued: dict[Jack, tuple[np.ndarray, float]] = {}
        self._played: dict[int, dict[Jack, tuple[np.ndarray, float]]] = {}

    @staticmethod
    def ramp(serial: str, channel: int, scan: int, start: int, n: int) -> np.ndarray:
        """The int16 codes an unwired input reads: a ramp offset by board, channel and scan."""
        offset = int(serial) % 1009 * 31 + 1000 * channel + 100 * scan
        return ((np.arange(start, start + n, dtype=np.int64) + offset) % 65536
                - 32768).astype(np.int16)

    def load_output(self, serial: str, channels: Sequence[int], codes: np.ndarray,
                    range_v: float) -> None:
        with self._cond:
            for i, ch in enumerate(channels):
                self._queued[(serial, ch)] = (np.array(codes[:, i], dtype=np.int16), range_v)

    def fire_trigger(self) -> int:
        with self._cond:
            self._scan += 1
            self._played[self._scan] = self._queued
            self._played.pop(self._scan - 2, None)
            self._queued = {}
            self._cond.notify_all()
            return self._scan

    def wait_for_trigger(self, after_scan: int, timeout_s: float) -> int | None:
        with self._cond:
            if self._cond.wait_for(lambda: self._scan > after_scan, timeout_s):
                return self._scan
            return None

    def input_codes(self, serial: str, channels: Sequence[InputChannel], scan: int,
                    start: int, n: int) -> np.ndarray:
        with self._cond:
            played = self._played.get(scan, {})
        sources = {inp: out for out, inp in self.wires.items()}
        columns = []
        for ch in channels:
            source = sources.get((serial, ch.channel))
            if source is None:
                columns.append(self.ramp(serial, ch.channel, scan, start, n))
                continue
            wave, out_range = played.get(source, (np.zeros(0, np.int16), 10.0))
            seg = np.zeros(n, np.float64)
            part = wave[start: start + n]
            seg[: len(part)] = part * (out_range / ch.range_v)
            columns.append(np.clip(np.round(seg), -CODE_FULL_SCALE,
                                   CODE_FULL_SCALE - 1).astype(np.int16))
        return np.stack(columns, axis=1) if columns else np.zeros((n, 0), np.int16)
