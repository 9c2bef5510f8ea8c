"""Bounded numbers for argparse: every numeric option of `micam` says the range it accepts.

`integer(lo, hi)`, `number(lo, hi)` and `positive(hi)` are argparse types, and the ranges that
several commands share are named below. A value outside the range, or no number at all
(`nan`, `inf`, `1.5` for an integer), is argparse's usage error naming the option, the value
and the range (`micam live video: error: argument --grid: 100000 is not an integer from 2 to
1000`, exit 2), before anything runs or allocates. An option that fills a model field with a
range of its own (the simulation's, the protocol's) takes the same range: the model is not
imported here, to keep `micam --help` light, and tests/micam/test_numeric_options.py checks
that the two agree, and walks the whole parser to fail on a numeric option that takes any
value. The burst's options are the exception: they take the burst's own bounds from
acquisition.contracts.burst (which loads pydantic and the kernel's constants only), and
tests/acquisition/test_burst.py checks every model and option of a burst against them.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from acquisition.contracts.burst import MAX_PERIODS
from acquisition.contracts.errors import UserError
from kernel.stimulus import MAX_MLS_ORDER, MIN_MLS_ORDER


def _plain(value: float) -> str:
    """A bound as a person writes it: 2, 0.95, 4294967295, 1e-06."""
    return f"{value:.15g}"


@dataclass(frozen=True)
class Bounded:
    """An argparse type: `parse` the text, then refuse a value below `lo` (or at it, when
    `above`) or beyond `hi`. `what` names the kind of value in the message ("an integer"),
    `show` writes a bound, `unit` follows the range (" s")."""

    parse: Callable[[str], Any]
    what: str
    lo: float
    hi: float
    above: bool = False
    unit: str = ""
    show: Callable[[float], str] = _plain

    def __call__(self, text: str) -> Any:
        try:
            value = self.parse(text)
        except (ValueError, UserError):  # float()'s, or a parser of micam's own
            raise argparse.ArgumentTypeError(f"{text!r} is not {self.describe()}") from None
        low_ok = value > self.lo if self.above else value >= self.lo
        if not (math.isfinite(value) and low_ok and value <= self.hi):
            raise argparse.ArgumentTypeError(f"{text} is not {self.describe()}")
        return value

    def describe(self) -> str:
        """'an integer from 2 to 1000', 'a number above 0 and at most 60 s'."""
        lo, hi = self.show(self.lo), self.show(self.hi)
        if self.above:
            return f"{self.what} above {lo} and at most {hi}{self.unit}"
        return f"{self.what} from {lo} to {hi}{self.unit}"


def integer(lo: int, hi: int) -> Bounded:
    """An integer option from `lo` to `hi`, both included."""
    return Bounded(int, "an integer", lo, hi)


def number(lo: float, hi: float, unit: str = "", above: bool = False) -> Bounded:
    """A (finite) number option from `lo` (excluded when `above`) to `hi`; `unit` follows the
    range in the message (" s", " m", " Hz")."""
    return Bounded(float, "a number", lo, hi, above, unit)


def positive(hi: float, unit: str = "") -> Bounded:
    """A number above 0 and at most `hi`."""
    return number(0.0, hi, unit, above=True)


# The ranges that several commands share.
SEED = integer(0, 2**32 - 1)
"""A seed of a simulation or of a random draw."""
REPLY_TIMEOUT = positive(3600, " s")
"""The wait for one reply of the daemon."""
LONG_WAIT = positive(7 * 86_400, " s")
"""The wait for a capture or a session to finish (a week at most)."""
BAND_HZ = number(10, 100_000, " Hz")
"""A band's centre frequency."""
FRACTION = integer(1, 48)
"""Bands of 1/N octave."""
RANGE_DB = positive(120, " dB")
"""A map's dynamic range, below its peak."""
DEPTH_M = number(0.05, 100, " m")
"""The distance of a scan plane in front of the camera."""
TARGET_MM = positive(100, " mm")
"""A predicted mean microphone accuracy to reach."""
POSE = integer(0, 9_999)
"""A pose number (a session has at most 10 000 poses)."""
SPEAKER = integer(0, 999)
"""A speaker's number at a pose."""
MLS_ORDER = integer(MIN_MLS_ORDER, MAX_MLS_ORDER)
"""The order of a burst's MLS: the burst's own bounds (acquisition.contracts.burst)."""
BURST_PERIODS = integer(1, MAX_PERIODS)
"""The periods of a burst's MLS: the burst's own bounds."""
