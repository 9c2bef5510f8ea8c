"""The air: Cramer's speed of sound and what a sensor's reading implies."""

from __future__ import annotations

import numpy as np
import pytest

from kernel.air import AirReading, speed_of_sound


def test_cramer_reference_values():
    assert speed_of_sound(0.0, 0.0) == pytest.approx(331.45, abs=0.05)
    # about 0.6 m/s per kelvin, humidity raises c
    c = speed_of_sound(np.array([19.5, 20.5]), 0.0)
    assert np.diff(c)[0] == pytest.approx(0.59, abs=0.02)
    assert speed_of_sound(20.0, 1.0) > speed_of_sound(20.0, 0.0)


def test_a_reading_gives_c_with_the_sensors_accuracy():
    """0.1 K and 2 % RH at 20 degC: 0.062 m/s and 0.025 m/s, added in quadrature."""
    c, std = AirReading(temperature_c=20.0, temperature_std_k=0.1, relative_humidity=0.45,
                        relative_humidity_std=0.02, pressure_std_pa=0.0).speed_of_sound()
    assert c == pytest.approx(speed_of_sound(20.0, 0.45), rel=1e-12)
    assert std == pytest.approx(np.hypot(0.0621, 0.0251), rel=0.03)
    # without a hygrometer the humidity's range dominates
    assert AirReading(temperature_c=20.0, temperature_std_k=0.1).speed_of_sound()[1] > 0.5
