"""The air a capture happens in: its speed of sound, the readings of a sensor, the sensor.

The speed of sound and the metric scale of a calibration are confounded (scaling every length
and c by one factor changes no time of flight), so only an absolute length or a measured air
state can pin c. An air sensor beside the array (a thermometer, ideally with a hygrometer)
gives that: c = speed_of_sound(T, RH, p) to about 0.6 m/s per kelvin and 1.3 m/s per unit of
relative humidity at 20 degC. The capture sequencer stores one `AirReading` per pose
(`air.json` in the step) when it has a sensor; the calibration turns them into a prior on c.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

AIR_FILE = "air.json"
"""The per-step file of an air reading."""
NOMINAL_SPEED_OF_SOUND_M_S = 343.0
"""c when nothing better is known (dry air at about 20 degC): a start value, never a result."""


class SpeedOfSoundPrior(NamedTuple):
    """A known speed of sound and how well it is known: a prior of the calibration's c."""

    c_m_s: float
    std_m_s: float


class AirReading(BaseModel):
    """One reading of the air sensor, with the sensor's stated accuracy (1 sigma).

    The accuracies are systematic (a calibration error common to all readings), so averaging
    readings does not shrink them.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    temperature_c: float = Field(ge=-40.0, le=60.0)
    temperature_std_k: float = Field(gt=0.0, le=10.0)
    relative_humidity: float = Field(default=0.5, ge=0.0, le=1.0)
    relative_humidity_std: float = Field(default=0.5, ge=0.0, le=1.0,
                                         description="0.5: no hygrometer (anything goes)")
    pressure_pa: float = Field(default=101_325.0, ge=50_000.0, le=120_000.0)
    pressure_std_pa: float = Field(default=2_000.0, ge=0.0, le=50_000.0)

    def speed_of_sound(self) -> SpeedOfSoundPrior:
        """(c, std) in m/s implied by the reading and its stated accuracies (first order)."""
        c = float(speed_of_sound(self.temperature_c, self.relative_humidity, self.pressure_pa))
        parts = []
        for name, std, step in (("temperature_c", self.temperature_std_k, 0.01),
                                ("relative_humidity", self.relative_humidity_std, 0.001),
                                ("pressure_pa", self.pressure_std_pa, 10.0)):
            shifted = self.model_copy(update={name: getattr(self, name) + step})
            dc = float(speed_of_sound(shifted.temperature_c, shifted.relative_humidity,
                                      shifted.pressure_pa)) - c
            parts.append(dc / step * std)
        return SpeedOfSoundPrior(c, float(np.sqrt(np.sum(np.square(parts)))))


def piston_directivity(freqs_hz: np.ndarray, sin_theta: np.ndarray, radius_m: float,
                       speed_of_sound_m_s: float) -> np.ndarray:
    """How a speaker radiates into the air off its axis: the far-field amplitude 2 J1(x) / x,
    x = k a sin(theta), of a baffled piston of radius a (1 on axis; real, so it changes no
    arrival time), shape sin_theta.shape + freqs_hz.shape."""
    from scipy.special import j1

    k = 2 * np.pi * np.asarray(freqs_hz, dtype=np.float64) / speed_of_sound_m_s
    x = np.multiply.outer(np.abs(np.asarray(sin_theta, dtype=np.float64)), k * radius_m)
    safe = np.where(x < 1e-6, 1.0, x)
    return np.where(x < 1e-6, 1.0, 2.0 * j1(safe) / safe)


@runtime_checkable
class AirSensor(Protocol):
    """Anything that reads the air beside the array (a real sensor, or the simulated lab's)."""

    @property
    def name(self) -> str: ...

    def read(self) -> AirReading:
        """The air now."""
        ...


# Cramer (1993), J. Acoust. Soc. Am. 93(5) 2510-2516, Table III, coefficients a0..a15.
_CRAMER = (
    331.5024, 0.603055, -0.000528, 51.471935, 0.1495874, -0.000782, -1.82e-7, 3.73e-8,
    -2.93e-10, -85.20931, -0.228525, 5.91e-5, -2.835149, -2.15e-13, 29.179762, 0.000486,
)  # fmt: skip


def speed_of_sound(
    temperature_c: float | np.ndarray,
    relative_humidity: float | np.ndarray = 0.5,
    pressure_pa: float | np.ndarray = 101_325.0,
    co2_mole_fraction: float = 0.0004,
) -> float | np.ndarray:
    """Speed of sound in air (m/s) from Cramer's (1993) formula (the simulated world's air
    too, so that a simulated thermometer means what a real one does).

    Accuracy: Cramer states an uncertainty below 300 ppm (about 0.1 m/s) for 0-30 degC,
    60-110 kPa, water-vapour mole fraction up to 0.06 and CO2 up to 1 %. In practice the
    thermometer dominates: c changes by 0.6 m/s per kelvin and by ~0.6 m/s between dry and
    saturated air at 20 degC, so the paper's +-0.1 m/s needs +-0.17 K. The water-vapour mole
    fraction uses the enhancement factor and saturation vapour pressure of Davis (1992),
    as in Cramer's appendix.

    Args:
        temperature_c: air temperature in degC.
        relative_humidity: 0..1.
        pressure_pa: static pressure in Pa.
        co2_mole_fraction: 0.0004 (400 ppm) by default.
    """
    t = np.asarray(temperature_c, dtype=float)
    p = np.asarray(pressure_pa, dtype=float)
    kelvin = t + 273.15
    enhancement = 1.00062 + 3.14e-8 * p + 5.6e-7 * t**2
    saturation = np.exp(1.2811805e-5 * kelvin**2 - 1.9509874e-2 * kelvin + 34.04926034
                        - 6.3536311e3 / kelvin)  # fmt: skip
    xw = np.asarray(relative_humidity, dtype=float) * enhancement * saturation / p
    xc = co2_mole_fraction
    a = _CRAMER
    c = (
        a[0] + a[1] * t + a[2] * t**2
        + (a[3] + a[4] * t + a[5] * t**2) * xw
        + (a[6] + a[7] * t + a[8] * t**2) * p
        + (a[9] + a[10] * t + a[11] * t**2) * xc
        + a[12] * xw**2 + a[13] * p**2 + a[14] * xc**2 + a[15] * xw * p * xc
    )  # fmt: skip
    return float(c) if c.ndim == 0 else c
