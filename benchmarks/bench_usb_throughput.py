"""Sustained throughput of the USB driver through the emulated boards, and its CPU share.

The paper's hardware: 3 DT9836-12-2 + 6 DT9816-A, 72 channels on one clock. Two runs through
the real driver (pyusb, reader and watcher threads, `daq.SyncGroup`) on the emulated bus:

1. free-running: the emulated clock has no wall-time pace, so the figure is how many samples
   per second (all channels) the driver can move: its headroom over the 6.9 MS/s of the array;
2. real time at 96 kS/s: the emulated clock ticks in wall time, as the hardware does; the
   figure is the process's CPU time over wall time (1.0 = one core busy), and the driver's own
   share after subtracting the CPU spent inside the emulated device (measured per call with
   thread CPU time, so its sleeps do not count).

Prints the figures and writes them as JSON to benchmarks/results/usb_throughput.json.

    .venv/bin/python benchmarks/bench_usb_throughput.py [--seconds 5] [--realtime-seconds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import threading
import time
from pathlib import Path
from typing import Any

from daq import InputChannel, OutputChannel, ScanConfig, SyncGroup
from daq.usb import open_boards
from sim.usb import EmulatedBackend, EmulatedBus, LoopbackBench

RATE_HZ = 96_000.0
BOARDS = ([("DT9836-12-2", f"{36_00 + i}") for i in range(3)]
          + [("DT9816-A", f"{16_00 + i}") for i in range(6)])
CHANNELS = 3 * 12 + 6 * 6


class _TimedBackend(EmulatedBackend):
    """The emulated backend, adding up the CPU time its transfers spend in the emulator."""

    def __init__(self, bus: EmulatedBus) -> None:
        super().__init__(bus)
        self.cpu_s = 0.0
        self._lock = threading.Lock()

    def _timed(self, method: Any, *args: Any) -> Any:
        t0 = time.thread_time()
        try:
            return method(*args)
        finally:
            spent = time.thread_time() - t0
            with self._lock:
                self.cpu_s += spent

    def bulk_read(self, *args: Any) -> int:
        return self._timed(super().bulk_read, *args)

    def bulk_write(self, *args: Any) -> int:
        return self._timed(super().bulk_write, *args)


def _configs(n: int) -> list[ScanConfig]:
    configs = []
    for i, (model, _) in enumerate(BOARDS):
        n_in = 12 if model.startswith("DT9836") else 6
        outputs = (OutputChannel(channel=0), OutputChannel(channel=1)) if i == 0 else ()
        configs.append(ScanConfig(inputs=tuple(InputChannel(channel=c) for c in range(n_in)),
                                  outputs=outputs, sample_rate_hz=RATE_HZ,
                                  samples_per_channel=n))
    return configs


def _run(seconds: float, realtime: bool, block_samples: int) -> dict[str, float]:
    bus = EmulatedBus(LoopbackBench(), BOARDS, realtime=realtime)
    backend = _TimedBackend(bus)
    group = SyncGroup(open_boards([s for _, s in BOARDS], backend=backend))
    n = round(seconds * RATE_HZ)
    group.configure(_configs(n))
    backend.cpu_s = 0.0
    wall0, cpu0 = time.perf_counter(), time.process_time()
    recording = group.acquire(block_samples=block_samples, timeout_s=10.0)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    group.close()
    assert recording.codes.shape == (n, CHANNELS)
    return {
        "samples_per_channel": n,
        "wall_s": wall,
        "cpu_s": cpu,
        "emulator_cpu_s": backend.cpu_s,
        "samples_per_s": n * CHANNELS / wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0,
                        help="scan length of the free-running run, in seconds at 96 kS/s")
    parser.add_argument("--realtime-seconds", type=float, default=3.0)
    parser.add_argument("--block", type=int, default=9600, help="samples per SyncGroup read")
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "usb_throughput.json")
    args = parser.parse_args()

    free = _run(args.seconds, realtime=False, block_samples=args.block)
    real = _run(args.realtime_seconds, realtime=True, block_samples=args.block)
    realtime_rate = CHANNELS * RATE_HZ
    result = {
        "boards": [m for m, _ in BOARDS],
        "channels": CHANNELS,
        "rate_hz": RATE_HZ,
        "free_running": {**free, "times_real_time": free["samples_per_s"] / realtime_rate},
        "real_time": {
            **real,
            "cpu_share_process": real["cpu_s"] / real["wall_s"],
            "cpu_share_driver": (real["cpu_s"] - real["emulator_cpu_s"]) / real["wall_s"],
        },
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    rt = result["real_time"]
    print(f"{CHANNELS} channels on {len(BOARDS)} emulated boards through the USB driver")
    print(f"  free-running: {free['samples_per_s'] / 1e6:.1f} MS/s sustained "
          f"({result['free_running']['times_real_time']:.1f} x the 6.9 MS/s of 72 ch at 96 kS/s)")
    print(f"  real time at 96 kS/s: process CPU {100 * rt['cpu_share_process']:.0f} % of one "
          f"core, driver alone {100 * rt['cpu_share_driver']:.0f} % "
          f"(wall {rt['wall_s']:.2f} s for {args.realtime_seconds:.1f} s of signal)")
    print(f"  written to {args.out}")


if __name__ == "__main__":
    main()
