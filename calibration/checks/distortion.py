"""A speaker driven into distortion, found in its reference recording.

An MLS measurement of a linear system gives its impulse response, with nothing but noise
away from it. A nonlinearity (a speaker or amplifier driven beyond its limit) spreads its
harmonics over the whole period of the MLS's circular correlation as spurious peaks. The
reference microphone, 2 mm from the diaphragm, hears the speaker 40-50 dB above the room, so
each speaker's reference recording correlated with the sequence it played shows its own
distortion floor; a speaker is judged against the session's others, never a fixed level.

The times of flight correlate the pose recordings with that same reference recording, which
holds the same distortion, so a distorted speaker's times of flight stay near those of the
direct sound, but not quite: 20-pose realistic sessions with one speaker at drive 3 gave
0.043 and 0.033 mm kept, 0.043 and 0.029 mm with its bursts left out (0.039 and 0.024 mm
without the mistake). Its bursts are left out (calibration.checks.capture_checks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acquisition.contracts.rig_description import BurstLayout
from kernel.stimulus import mls_burst

DISTORTED_DB = 15.0
"""A speaker whose distortion floor lies this far (dB) above the median speaker's is driven
into distortion. Measured on a 20-pose realistic session (order-12 MLS): clean speakers
-83.2 to -83.5 dB (RMS of the correlation away from its peak, over the peak), a speaker in
tanh saturation -59 dB at drive 1 (its peak compressed by a quarter), -47.6 dB at drive 3."""

CLOSE_LEVEL_DB = 20.0
"""A reference recording this far (dB) below the median speaker's was not made at the
diaphragm (a saturated speaker's lies 5 dB below at drive 3, a swapped speaker's 50 dB): its
floor is the room's, not a distortion."""

RESPONSE_SPAN_S = (-5e-4, 4e-3)
"""(start, end) from the correlation's peak that holds the speaker's and the reference
microphone's own response (and the room's first reflections, 40 dB down): left out of the
floor."""


@dataclass(frozen=True)
class ReferenceFloors:
    """What each speaker's reference recording says of its playback.

    Attributes:
        floor_db: (S,) the standard deviation of the recording's circular correlation with
            one period of the MLS it played, outside `RESPONSE_SPAN_S` of the peak, over the
            peak, in dB.
        level_db: (S,) the correlation's peak over the median speaker's, in dB: a reference
            recording not made at the diaphragm (a swapped cable: the speaker that played is
            a hand's width away; a speaker that did not play) lies 50 dB or more below.
    """

    floor_db: np.ndarray
    level_db: np.ndarray

    @property
    def close(self) -> np.ndarray:
        """(S,) the recordings made at the diaphragm (`CLOSE_LEVEL_DB`)."""
        return self.level_db > -CLOSE_LEVEL_DB

    def typical_floor_db(self) -> float:
        """The median floor of the recordings made at the diaphragm (NaN without any)."""
        return float(np.median(self.floor_db[self.close])) if self.close.any() else np.nan


def reference_floors(references: np.ndarray, burst: BurstLayout, fs: float) -> ReferenceFloors:
    """The `ReferenceFloors` of the reference recordings `references` ((S, n) samples of whole
    recordings, bursts laid out as `burst`, sampled at `fs`)."""
    sequence = mls_burst(burst.mls_order)
    n = sequence.size
    steady = burst.steady_window
    first = burst.silence_before_samples if steady is None else steady[0]
    period = np.asarray(references[:, first:first + n], dtype=np.float64)
    if period.shape[-1] < n:
        raise ValueError(f"reference recordings of {references.shape[-1]} samples hold no "
                         f"whole MLS period of {n} samples after sample {first}")
    spectrum = np.fft.rfft(period, axis=-1) * np.conj(np.fft.rfft(sequence))
    correlation = np.fft.irfft(spectrum, n=n, axis=-1)
    peak = np.abs(correlation).argmax(axis=-1)
    lag = (np.arange(n)[None, :] - peak[:, None]) % n
    lead, tail = (round(abs(t) * fs) for t in RESPONSE_SPAN_S)
    away = (lag > tail) & (lag < n - lead)
    top = np.abs(correlation).max(axis=-1)
    # the spread, not the RMS: an MLS's autocorrelation is -1 off its peak, so a response
    # (or an offset of the recording) leaves a constant there, which is no distortion
    # (NaN, no distortion judged, where a short MLS leaves no lag outside the response)
    floor = np.array([np.std(row[mask]) if mask.any() else np.nan
                      for row, mask in zip(correlation, away, strict=True)])
    with np.errstate(divide="ignore", invalid="ignore"):
        return ReferenceFloors(20.0 * np.log10(floor / top),
                               20.0 * np.log10(top / np.median(top)))


def distorted_speakers(floors: ReferenceFloors) -> np.ndarray:
    """Indices of the speakers whose distortion floor lies `DISTORTED_DB` above the median
    speaker's, among those whose reference recording was made at the diaphragm (within
    `CLOSE_LEVEL_DB` of the median speaker's level; the others' floor is the room's)."""
    if floors.close.sum() < 2:
        return np.array([], dtype=int)
    return np.flatnonzero(floors.close
                          & (floors.floor_db > floors.typical_floor_db() + DISTORTED_DB))
