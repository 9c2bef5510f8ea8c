"""A short scan on one board, reporting rates, levels and any error (`micam daq selftest`).

It knows the board through the `Board` protocol only, so the USB driver and the audio backend
(`daq.audio`) share it.
"""

from __future__ import annotations

import time

import numpy as np
from pydantic import BaseModel, ConfigDict

from ._config import InputChannel, ScanConfig
from ._errors import DaqError
from ._interface import Board, codes_to_volts

SELFTEST_RATE_HZ = 96_000.0
"""The array's real-time rate; boards slower than this are tested at their own maximum."""


class ChannelLevel(BaseModel):
    """Levels seen on one input during the self-test (volts at the ±10 V range)."""

    model_config = ConfigDict(frozen=True)

    channel: int
    mean_v: float
    rms_v: float
    min_code: int
    max_code: int


class SelftestReport(BaseModel):
    """What a self-test found on one board.

    Attributes:
        board: "model serial N".
        rate_hz: the configured sample rate, samples per second per channel.
        samples: samples per channel asked for.
        received: samples per channel received before the end or the error.
        elapsed_s: wall time from the start to the last sample.
        achieved_rate_hz: received / elapsed_s (close to rate_hz on a real board).
        channels: levels per input channel.
        error: the error that ended the test, or None.
    """

    model_config = ConfigDict(frozen=True)

    board: str
    rate_hz: float
    samples: int
    received: int
    elapsed_s: float
    achieved_rate_hz: float
    channels: tuple[ChannelLevel, ...]
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None and self.received == self.samples


def selftest(board: Board, seconds: float = 1.0) -> SelftestReport:
    """Scan every input of `board` for `seconds` on its own clock and report what came in."""
    model = board.identity.model
    rate = min(SELFTEST_RATE_HZ, model.max_input_rate_hz)
    n = max(1, round(seconds * rate))
    config = ScanConfig(inputs=tuple(InputChannel(channel=c) for c in range(model.n_inputs)),
                        sample_rate_hz=rate, samples_per_channel=n)
    block = max(1, round(rate / 10))
    chunks: list[np.ndarray] = []
    error = None
    t0 = t1 = time.monotonic()
    try:
        board.configure(config)
        board.arm()
        t0 = time.monotonic()
        board.start()
        received = 0
        while received < n:
            got = board.read(min(block, n - received), timeout_s=max(2.0, 20 * block / rate))
            chunks.append(got.codes)
            received += got.n_samples
        t1 = time.monotonic()
    except DaqError as e:
        error = str(e)
        t1 = time.monotonic()
    finally:
        try:
            board.stop()
        except DaqError as e:
            error = error or str(e)
    codes = np.concatenate(chunks) if chunks else np.zeros((0, model.n_inputs), np.int16)
    volts = codes_to_volts(codes, 10.0)
    levels = tuple(
        ChannelLevel(channel=c, mean_v=float(volts[:, c].mean()) if len(codes) else 0.0,
                     rms_v=float(np.sqrt((volts[:, c] ** 2).mean())) if len(codes) else 0.0,
                     min_code=int(codes[:, c].min()) if len(codes) else 0,
                     max_code=int(codes[:, c].max()) if len(codes) else 0)
        for c in range(model.n_inputs)
    )
    elapsed = max(t1 - t0, 1e-9)
    return SelftestReport(board=str(board.identity), rate_hz=rate, samples=n,
                          received=len(codes), elapsed_s=elapsed,
                          achieved_rate_hz=len(codes) / elapsed, channels=levels, error=error)
