"""The burst: what a speaker plays and a recording holds, defined once.

A burst is silence, `periods` periods of a maximum-length sequence of `mls_order` back to back,
then the recording while it dies away. Three documents state one: the capture configuration
(`BurstConfig`, [burst] of a daemon's hardware: pre_samples, post_samples, and the amplitude
it is played at), the rig and array description that calibration reads (`BurstLayout`,
[burst] of an import: silence_before_samples, silence_after_samples, and what a foreign
recorder kept after that), and the simulation's options (mls_order, mls_periods). Their keys
stay as the files already written spell them; what each means and which values it takes are
the field types below, which all three models use, and `BurstConfig.as_recorded` is the one way
from a capture's burst to its description's. The command line's options take the same bounds
(micam/commands/bounded.py), and tests/acquisition/test_burst.py fails if any of them drifts.

This module imports pydantic and the kernel's constants only, so that `micam`'s parser can
read the bounds without numpy.
"""

from __future__ import annotations

import math
from typing import Annotated, Final

from pydantic import Field

from kernel.stimulus import MAX_MLS_ORDER, MIN_MLS_ORDER, mls_length

from .config_model import ConfigModel

MAX_PERIODS: Final = 8
"""The most periods a burst may play back to back (one recording is never more than eight
sequences long)."""

MlsOrder = Annotated[int, Field(
    ge=MIN_MLS_ORDER, le=MAX_MLS_ORDER, examples=[14],
    description="order of the MLS: one period is 2**mls_order - 1 samples")]
Periods = Annotated[int, Field(
    ge=1, le=MAX_PERIODS, examples=[2],
    description="periods of the sequence played back to back; with 2 or more the last is "
                "correlated circularly, which keeps a room's reflections off the direct sound")]
SilenceBefore = Annotated[int, Field(
    ge=0, examples=[512], description="samples recorded before the sequence starts")]
SilenceAfter = Annotated[int, Field(
    ge=0, examples=[2048],
    description="samples recorded after the sequence's last period, while it dies away")]

MIN_STEADY_PERIOD_S: Final = 0.04
"""Shortest MLS period (seconds) that bursts of two or more periods may have: their circular
correlation spans lags of +-half a period, and the positive half must hold the longest path
calibration searches (6 m, 17.5 ms) with room to spare for early reflections."""


def steady_mls_order(sample_rate_hz: float) -> int:
    """The lowest MLS order whose period lasts MIN_STEADY_PERIOD_S at `sample_rate_hz`."""
    return math.ceil(math.log2(MIN_STEADY_PERIOD_S * sample_rate_hz + 1))


def holds_the_room(mls_order: int, sample_rate_hz: float) -> bool:
    """Whether a period of an MLS of `mls_order` lasts MIN_STEADY_PERIOD_S or more at
    `sample_rate_hz` (so that two or more periods may be played)."""
    return mls_length(mls_order) / sample_rate_hz >= MIN_STEADY_PERIOD_S


def folding(mls_order: int, periods: int, sample_rate_hz: float) -> str | None:
    """What is wrong with `periods` >= 2 of a sequence too short to hold the room ("2 periods
    of an MLS of order 9 (5.3 ms at 96000 Hz) fold the room onto the direct sound"); None when
    nothing is. Each caller adds the fix in the words of its own file or options."""
    if periods < 2 or holds_the_room(mls_order, sample_rate_hz):
        return None
    period_ms = 1e3 * mls_length(mls_order) / sample_rate_hz
    return (f"{periods} periods of an MLS of order {mls_order} ({period_ms:.1f} ms at "
            f"{sample_rate_hz:g} Hz) fold the room onto the direct sound")


class BurstLayout(ConfigModel):
    """What each recording holds, in samples: silence, `periods` periods of the test sequence
    (an MLS of `mls_order`) back to back, the silence played after them, and what the
    recorder kept after that."""

    silence_before_samples: SilenceBefore = 0
    mls_order: MlsOrder
    periods: Periods = 1
    silence_after_samples: SilenceAfter = 0
    extra_recorded_samples: int = Field(
        default=0, ge=0, examples=[0],
        description="samples the recorder kept after the silence that followed the sequence")

    @property
    def sequence_samples(self) -> int:
        return mls_length(self.mls_order)

    @property
    def n_samples(self) -> int:
        """Length of one recording, samples per channel."""
        return (self.silence_before_samples + self.periods * self.sequence_samples
                + self.silence_after_samples + self.extra_recorded_samples)

    def period_problem(self, sample_rate_hz: float, where: str) -> str | None:
        """What is wrong with periods >= 2 of a sequence this short at `sample_rate_hz`
        (None: nothing): its circular correlation must hold every path calibration searches
        (6 m) and a room's early reflections, which a period shorter than
        `MIN_STEADY_PERIOD_S` would fold onto the direct sound."""
        problem = folding(self.mls_order, self.periods, sample_rate_hz)
        if problem is None:
            return None
        return (f"{where}: {problem}; write mls_order = {steady_mls_order(sample_rate_hz)} or "
                f"more (a period of at least {1e3 * MIN_STEADY_PERIOD_S:g} ms), or periods = 1")

    @property
    def steady_window(self) -> tuple[int, int] | None:
        """(first, stop) samples of the last period, where every arrival is periodic; None
        with a single period."""
        if self.periods < 2:
            return None
        start = self.silence_before_samples + (self.periods - 1) * self.sequence_samples
        return start, start + self.sequence_samples


class BurstConfig(ConfigModel):
    """The MLS burst each speaker plays: `pre_samples` of silence, `periods` periods of an MLS
    of `mls_order` at `amplitude_v` volts back to back, then `post_samples` of recording while
    it dies away.

    Why more than one period: after the first, every microphone hears the periodic steady
    state (the direct sound and every reflection of a period arrive within it), so one period
    correlated circularly against the reference's is exactly the periodic impulse response: a
    room's reflections are clean pulses that leave the direct one alone, and the sequence's
    flat spectrum costs no precision (calibration.acoustic.delay_estimation). One period (the
    default, and what sessions recorded before it existed hold) is a burst whose reflections
    bias delays by tens of nanoseconds in a room."""

    mls_order: MlsOrder = 14
    amplitude_v: float = Field(default=1.0, gt=0, le=10)
    pre_samples: SilenceBefore = 512
    post_samples: SilenceAfter = 2048
    periods: Periods = 1

    def as_recorded(self) -> BurstLayout:
        """What each recording of this burst holds, as calibration reads it (the description's
        burst): a micam recording keeps nothing after `post_samples`."""
        return BurstLayout(silence_before_samples=self.pre_samples, mls_order=self.mls_order,
                           periods=self.periods, silence_after_samples=self.post_samples)

    @property
    def n_samples(self) -> int:
        """Length of one recording, samples per channel."""
        return self.as_recorded().n_samples
