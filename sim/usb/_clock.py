"""The shared sample clock and trigger line of the emulated boards.

The master board (internal clock, software trigger) fires the bench's trigger through this
object and so starts the shared clock; followers wait for the bench's trigger and sample on
the same clock. With `realtime` the clock ticks in wall time (samples appear at the sample
rate, as on hardware); without it every sample of a triggered scan is available at once, so the
emulated boards run as fast as the driver can read.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from sim.analog_bench import AnalogBench


class SharedClock:
    """Who fired the last trigger, when, and at what rate."""

    def __init__(self, bench: AnalogBench, realtime: bool,
                 now: Callable[[], float] = time.monotonic) -> None:
        """`now`: the wall clock in seconds that paces a real-time clock (tests pass their own)."""
        self.bench = bench
        self.realtime = realtime
        self._now = now
        self._lock = threading.Lock()
        self.last_scan = 0
        self._t0 = 0.0
        self._rate_hz = 0.0

    def fire(self, rate_hz: float) -> int:
        """Release the trigger with the clock at `rate_hz`; return the new scan number."""
        with self._lock:
            scan = self.bench.fire_trigger()
            self.last_scan, self._t0, self._rate_hz = scan, self._now(), rate_hz
            return scan

    def wait_for_trigger(self, after_scan: int, timeout_s: float) -> int | None:
        """The number of a scan started after `after_scan`, or None after `timeout_s`."""
        return self.bench.wait_for_trigger(after_scan, timeout_s)

    def edges(self, scan: int) -> float:
        """Clock edges since scan `scan` began (infinite when not real-time)."""
        if not self.realtime:
            return float("inf")
        with self._lock:
            if scan != self.last_scan:
                return 0.0
            return (self._now() - self._t0) * self._rate_hz

    def seconds_for(self, edges: float) -> float:
        """Wall time that `edges` clock edges take at the current rate."""
        with self._lock:
            return edges / self._rate_hz if self._rate_hz else 0.01
