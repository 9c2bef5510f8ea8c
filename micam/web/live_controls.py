"""What the page may change in the running live view, and the checks it passes first.

The operator picks the band (a base-2 octave or third-octave centre, `BANDS`), its width
(`fraction`), the map's dynamic range (dB below its peak, `RANGE_DB`) and the scan plane's
depth (metres in front of camera 0, `DEPTH_M`). A request names any of them (`live.view` on
`POST /api/command`, through the page's guard and body limits like every command); each value
is checked here (a number of the right kind within its bounds, a band the list holds and the
stream can carry) and a bad one is refused with one line naming it and what is allowed.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from calibration.errors import CalibrationInputError
from imaging.csm import band_bins, octave_band_centres
from imaging.live import FRACTIONS, LiveSettings

BAND_RANGE_HZ = (250.0, 16_000.0)
"""The lowest and highest band centre offered (both octave centres)."""
BANDS: dict[int, tuple[float, ...]] = {
    f: tuple(float(c) for c in octave_band_centres(*BAND_RANGE_HZ, f)) for f in FRACTIONS}
"""The band centres of each fraction, hertz (1000 * 2**(k / fraction))."""
RANGE_DB = (3.0, 60.0)
"""The dynamic range, dB below the map's peak, from and to."""
DEPTH_M = (0.1, 20.0)
"""The scan plane's depth, metres, from and to."""
ARGUMENTS = frozenset({"band_hz", "fraction", "range_db", "depth_m"})
"""The arguments of `live.view`."""


class LiveViewError(ValueError):
    """A `live.view` the page refuses; the message says which value and what is allowed."""


def view_of(settings: LiveSettings) -> dict[str, Any]:
    """What the operator may change of `settings`, by the names of ARGUMENTS."""
    return {"band_hz": settings.band_hz, "fraction": settings.fraction,
            "range_db": settings.dynamic_range_db, "depth_m": settings.depth_m}


def controls_of(settings: LiveSettings) -> dict[str, Any]:
    """The view as the page's controls show it, with what each may be set to."""
    return {**view_of(settings), "bands": {str(f): list(c) for f, c in BANDS.items()},
            "range_db_limits": list(RANGE_DB), "depth_m_limits": list(DEPTH_M)}


def retuned(settings: LiveSettings, args: dict[str, Any],
            sample_rate_hz: float | None) -> LiveSettings:
    """`settings` with the changes `args` asks for (any of ARGUMENTS), checked: against the
    stream's rate too when it is known (the band must hold a bin of the imager's blocks below
    Nyquist). LiveViewError says what is wrong."""
    unknown = set(args) - ARGUMENTS
    if unknown:
        raise LiveViewError(f"live.view takes {', '.join(sorted(ARGUMENTS))}, not "
                            f"{', '.join(sorted(unknown))}")
    number = _number(args, "fraction", (1, 3), settings.fraction)
    if number not in FRACTIONS:
        raise LiveViewError(f"fraction {number:g}: 1 (octave) or 3 (third octave)")
    fraction = int(number)
    band = _band(_number(args, "band_hz", BAND_RANGE_HZ, settings.band_hz), fraction)
    new = replace(settings, band_hz=band, fraction=fraction,
                  dynamic_range_db=_number(args, "range_db", RANGE_DB,
                                           settings.dynamic_range_db),
                  depth_m=_number(args, "depth_m", DEPTH_M, settings.depth_m))
    if sample_rate_hz is not None:
        try:
            band_bins(band, fraction, new.block_size, sample_rate_hz)
        except CalibrationInputError as exc:
            raise LiveViewError(f"band {band:.0f} Hz: {exc}") from None
    return new


def _number(args: dict[str, Any], key: str, bounds: tuple[float, float],
            current: float) -> float:
    """args[key] (or `current` when absent) as a finite number within `bounds`."""
    if key not in args:
        return current
    value = args[key]
    lo, hi = bounds
    if (isinstance(value, bool) or not isinstance(value, int | float)
            or not math.isfinite(value) or not lo <= value <= hi):
        raise LiveViewError(f"{key} {repr(value)[:40]} is not a number from {lo:g} to {hi:g}")
    return float(value)


def _band(band_hz: float, fraction: int) -> float:
    """The centre of BANDS[fraction] that `band_hz` names (within 1 %, so that a rounded
    4 kHz or 3150 Hz names its band)."""
    centres = np.array(BANDS[fraction])
    nearest = float(centres[np.argmin(np.abs(np.log(centres / band_hz)))])
    if abs(nearest / band_hz - 1) > 0.01:
        width = "an octave" if fraction == 1 else "a third-octave"
        raise LiveViewError(f"band_hz {band_hz:g} is not {width} centre; the nearest is "
                            f"{nearest:.0f} Hz")
    return nearest
