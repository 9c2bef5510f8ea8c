"""Is the calibration believable? Checks that turn a wrong answer into a clear error.

A calibration whose model does not fit its data must never look like a result. The checks
use the fit's own figures, against limits that a calibration of a real lab stays far inside
(figures from the simulated realistic lab, docs/calibration.md):

- the speed of sound must be one that air can have (-20..50 degC, any humidity: 319-367 m/s),
  and agree with a measured one (the air sensor, or a given c) within 5 standard deviations;
- the times of flight must fit: the robust spread of their residuals below 5 us (1.7 mm;
  a good fit leaves 0.01-0.1 us), and fewer than a quarter of them outliers;
- the corners must fit: the joint fit's reprojection RMS below 1.5 px (a good one: 0.1-0.3).

When the acoustic fit fails, `likely_cause` tries the one systematic mistake that is easy to
make and ruins everything: a pattern whose origin is at the other end of the board (the
opposite colour convention or corner order), which turns the rig by 180 degrees in its plane
and swaps speakers 1-4, 2-3, 5-6. If the rig fits that way, the error says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kernel.air import SpeedOfSoundPrior, speed_of_sound

from ..errors import CalibrationInputError
from ..solve.robust import robust_sigma

AIR_RANGE_M_S = (float(speed_of_sound(-20.0, 0.0)), float(speed_of_sound(50.0, 1.0)))
"""The speed of sound of air between -20 and 50 degC at any humidity (Cramer's formula)."""
MAX_TOF_SPREAD_S = 5e-6
MAX_FROZEN_TOF_SPREAD_S = 45e-6
"""The camera-frozen solution still carries the cameras' errors (a millimetre or two at most):
its residuals may spread more, but 45 us (15 mm; a median |residual| of 30 us) is beyond any
acoustic centre, rig tolerance or room, while a half-turned board, speakers or columns in the
wrong order give hundreds of microseconds. Failing there fails fast, before the joint fit."""
MAX_OUTLIER_FRACTION = 0.25
MAX_CORNER_RMS_PX = 1.5
MAX_PRIOR_DISAGREEMENT = 5.0


class ImplausibleCalibrationError(CalibrationInputError):
    """The calibration's own figures say its model is wrong (see the module docstring)."""


@dataclass(frozen=True)
class FitFigures:
    """What the checks look at, from any solution.

    Attributes:
        speed_of_sound_m_s, speed_of_sound_std_m_s: the fitted c (the session's mean).
        tof_residuals_s: (n_src, n_mic) residuals of the times of flight, NaN where missing.
        tof_outliers: (n_src, n_mic) those left out as outliers.
        corner_rms_px: per camera, the joint fit's reprojection RMS (empty: not fitted).
        known_speed_of_sound: (c, std) a measured speed of sound, if any.
    """

    speed_of_sound_m_s: float
    speed_of_sound_std_m_s: float
    tof_residuals_s: np.ndarray
    tof_outliers: np.ndarray
    corner_rms_px: dict[str, float]
    known_speed_of_sound: SpeedOfSoundPrior | None = None

    @property
    def tof_spread_s(self) -> float:
        """Robust standard deviation (1.4826 x median |r|) of the kept TOF residuals."""
        kept = np.isfinite(self.tof_residuals_s) & ~self.tof_outliers
        r = self.tof_residuals_s[kept]
        return robust_sigma(r) if r.size else float("inf")

    @property
    def outlier_fraction(self) -> float:
        valid = np.isfinite(self.tof_residuals_s)
        return float(self.tof_outliers[valid].mean()) if valid.any() else 1.0


def acoustic_problems(fig: FitFigures, frozen: bool = False) -> list[str]:
    """What is wrong with the acoustic fit (empty: nothing); `frozen`: the camera-frozen
    solution (its c held to a measured one, its residuals looser)."""
    problems = []
    lo, hi = AIR_RANGE_M_S
    c = fig.speed_of_sound_m_s
    if not lo <= c <= hi:
        problems.append(f"the speed of sound came out at {c:.1f} m/s, which air cannot have "
                        f"({lo:.0f}-{hi:.0f} m/s between -20 and 50 degC)")
    if fig.known_speed_of_sound is not None and not frozen:
        known, std = fig.known_speed_of_sound
        combined = float(np.hypot(std, fig.speed_of_sound_std_m_s))
        if abs(c - known) > MAX_PRIOR_DISAGREEMENT * combined:
            problems.append(f"the fitted speed of sound {c:.2f} m/s disagrees with the measured "
                            f"{known:.2f} +- {std:.2f} m/s")
    spread = fig.tof_spread_s
    if spread > (MAX_FROZEN_TOF_SPREAD_S if frozen else MAX_TOF_SPREAD_S):
        problems.append(f"the times of flight do not fit: their residuals spread by "
                        f"{spread * 1e6:.1f} us ({spread * 343e3:.1f} mm; a good fit leaves "
                        "0.01-0.1 us)")
    if not frozen and fig.outlier_fraction > MAX_OUTLIER_FRACTION:
        problems.append(f"{100 * fig.outlier_fraction:.0f} % of the times of flight had to be "
                        "left out as outliers")
    return problems


def optical_problems(fig: FitFigures) -> list[str]:
    """What is wrong with the cameras' fit (empty: nothing)."""
    return [f"camera {name}'s corners do not fit: {rms:.2f} px RMS (a good fit: 0.1-0.3 px)"
            for name, rms in fig.corner_rms_px.items() if rms > MAX_CORNER_RMS_PX]


def turned_rig(speakers_rig_m: np.ndarray, corners_x: int, corners_y: int,
               square_m: float) -> np.ndarray:
    """The stated speaker positions as the rig frame sees them when the pattern's origin is
    at the opposite inner corner (a half-turn in the board plane about the pattern's centre:
    the opposite colour convention, or the corner order read from the other end)."""
    centre = np.array([(corners_x - 1) * square_m / 2, (corners_y - 1) * square_m / 2])
    out = np.array(speakers_rig_m, dtype=float, copy=True)
    out[:, :2] = 2 * centre - out[:, :2]
    return out


def raise_if_implausible(problems: list[str], cause: str | None) -> None:
    """Raise ImplausibleCalibrationError listing `problems` and the likely cause."""
    if not problems:
        return
    text = "the calibration is not plausible, so no result was written: " + "; ".join(problems)
    if cause:
        text += f". Likely cause: {cause}"
    else:
        text += (". Likely causes: the rig description (speaker positions and their units, the "
                 "pattern's size and colour convention, the reference distance), recordings "
                 "that do not match the description (column order, sample rate), or an array "
                 "that sound reaches around obstacles; check them and calibrate again")
    raise ImplausibleCalibrationError(text)
