"""A reflector close to a microphone, found in the responses the joint fit measured.

A reflector a few millimetres from a capsule adds to everything it hears a copy of itself
d = 10-20 us later (one or two samples at 96 kS/s), g = 0.3-0.5 times as strong. In the band
the delays are measured in (to 20 kHz) that is a smooth filter 1 + g exp(-j w d): it lags
the microphone by about g d / (1 + g) (2-7 us) and its gain falls towards the band's top
(the comb's first notch, at 1 / 2d, lies just above it). No correlation peak shows the echo
apart (the compact pulse's main lobe is 0.1 ms wide), but the two signatures together do,
and they are the opposite of a capsule's: a capsule that lags more resonates lower, and its
gain rises towards the band's top.

Such an echo is a fixed filter on one microphone, which the joint fit models already: its
own delay (the echo's lag, 3.9 us on a 20-pose session) and its dispersion
(calibration.acoustic.responses.dispersion_delays) come out of its times of flight, so its position
stays as good as the others' (0.040 mm mean against 0.039 mm without the reflector). It is
noted, not left out.
"""

from __future__ import annotations

import numpy as np

from .capture_checks import Wiring
from ..result import CalibrationResult, Finding

CLOSE_REFLECTION_SCORE = 5.0
"""A microphone is taken to have a reflector beside it where its own delay's robust z-score
over the array's plus its top band's gain fall's (both from the array's median, in units of
1.4826 median absolute deviations) exceeds this. On a clean 20-pose realistic session the
largest of 48 microphones' is 2.4 (the two are uncorrelated there); an echo 16.5 us behind
the direct sound at 0.31 of it scores 10.3. The weakest the simulation draws by default (10
us, 0.3) scored 3.2 and is not named: it lags its microphone by 1.8 us and lowers its top
band by 3 % (on a capsule whose top rises), and costs the geometry nothing (0.0396 mm mean
against 0.0393 mm without it)."""

MIN_LAG_US = 1.5
"""Nor does a microphone that lags the array's median by less than this (microseconds). An
echo lags by about g d / (1 + g), 2.3-6.7 us for the simulated defaults, of which the own
delay shows 0.7 (the delay is a line through the bands that weights the top, where the
echo's phase bends back): 2.7 us for 3.9. On a 5-pose session with two speakers and a pose
left out the responses are few and their spread small, so two microphones that lag by 0.8
and 1.0 us scored 7."""

MID_BAND_HZ = (3_000.0, 10_000.0)
"""The bands whose median gain the top band's is compared with: above the room's
interference with the low bands, below the capsules' resonance."""


def _robust_z(values: np.ndarray) -> np.ndarray:
    """Each value's distance from the median in units of 1.4826 median absolute deviations
    (the standard deviation's robust estimate; a spread of 0 gives no z: NaN)."""
    median = np.nanmedian(values)
    spread = 1.4826 * np.nanmedian(np.abs(values - median))
    return (values - median) / spread if spread > 0 else np.full(values.shape, np.nan)


def close_reflections(result: CalibrationResult, wiring: Wiring) -> list[Finding]:
    """The noted findings of microphones with a reflector beside them
    (`CLOSE_REFLECTION_SCORE`), from `result`'s microphone responses and own delays (none
    without both); `wiring`: the session's microphones, for the channels' names."""
    responses = result.microphone_responses
    if responses is None or not responses.microphones:
        return []
    delays = {m.id: m.delay_s for m in result.microphones}
    rows = [r for r in responses.microphones if delays.get(r.id) is not None]
    if len(rows) < 8:
        return []
    f = np.asarray(responses.frequencies_hz)
    mid = (f >= MID_BAND_HZ[0]) & (f <= MID_BAND_HZ[1])
    gain = np.array([r.gain for r in rows])
    delay_us = 1e6 * np.array([delays[r.id] for r in rows], dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        fall = -np.log(gain[:, -1] / np.median(gain[:, mid], axis=1))
    score = _robust_z(delay_us) + _robust_z(fall)
    index = {int(i): k for k, i in enumerate(wiring.ids)}
    typical_pct = 100 * (1 - np.exp(-np.nanmedian(fall)))
    findings = []
    lagging = delay_us - float(np.nanmedian(delay_us)) > MIN_LAG_US
    for j in np.flatnonzero((score > CLOSE_REFLECTION_SCORE) & lagging):
        k = np.array([index[rows[j].id]])
        lag_us = delay_us[j] - float(np.nanmedian(delay_us))
        findings.append(wiring.finding(
            "close-reflection", "noted", k,
            evidence=f"{wiring.names(k)} hears an echo a sample or two behind the direct "
                     f"sound: it lags the array by {lag_us:.1f} us and its gain at "
                     f"{f[-1] / 1e3:.0f} kHz is {100 * (1 - np.exp(-fall[j])):.0f} % below its "
                     f"mid-band gain (the array's median {typical_pct:.0f} %; together "
                     f"{score[j]:.1f} robust sigmas from the array, where a capsule's lag and "
                     "fall go opposite ways)",
            advice="kept: its times of flight are late by about that lag, which the joint fit "
                   "takes as the microphone's own delay (with its dispersion), so its position "
                   "is unaffected; look for a surface within a few millimetres of it (a "
                   "cable, a mount, tape)"))
    return findings
