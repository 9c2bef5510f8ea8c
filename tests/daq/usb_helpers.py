"""Helpers shared by the USB driver and emulator tests: the paper's board mix, small scans."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from daq import InputChannel, OutputChannel, ScanConfig
from sim.usb import LoopbackBench

RATE = 96_000.0
BOARDS: list[tuple[str, str]] = [("DT9836-12-2", "1001"), ("DT9836-12-2", "1002"),
                                 ("DT9816-A", "1003")]
"""Two DT9836-12-2 (the first is the clock and trigger master) and a DT9816-A."""
LOOP = {("1001", 0): ("1003", 2), ("1001", 1): ("1002", 11)}
"""Cables: master output 0 -> DT9816-A input 2, master output 1 -> second DT9836 input 11."""


def loop_bench() -> LoopbackBench:
    return LoopbackBench(LOOP)


def scan_configs(n: int, boards: Sequence[tuple[str, str]] = BOARDS,
                 outputs_on_first: bool = True) -> list[ScanConfig]:
    """All inputs of every board, both outputs on the first board, `n` samples at 96 kS/s."""
    configs = []
    for i, (model, _) in enumerate(boards):
        n_in = 12 if model.startswith("DT9836-12") else 6
        outputs = ((OutputChannel(channel=0), OutputChannel(channel=1))
                   if i == 0 and outputs_on_first else ())
        configs.append(ScanConfig(inputs=tuple(InputChannel(channel=c) for c in range(n_in)),
                                  outputs=outputs, sample_rate_hz=RATE, samples_per_channel=n))
    return configs


def burst(n: int = 3000) -> np.ndarray:
    """Two output channels: a square wave and a ramp, as int16 codes (n, 2)."""
    k = np.arange(n)
    return np.stack([np.where(k % 50 < 25, 8000, -8000), (k % 4000) * 4 - 8000],
                    axis=1).astype(np.int16)
