"""Speed of sound: paper IV-G fit with and without a common latency; Cramer's formula."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.acoustic.speed_of_sound import fit_speed_of_sound


def synthetic(n: int, latency_s: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Distances 0.4-2 m with 0.5 mm camera noise and TOFs with 0.1 us noise, c = 343.2."""
    rng = np.random.default_rng(seed)
    true = rng.uniform(0.4, 2.0, n)
    tof = true / 343.2 + latency_s + 1e-7 * rng.standard_normal(n)
    return true + 5e-4 * rng.standard_normal(n), tof


def test_fit_recovers_c_and_a_common_latency_with_honest_errors():
    pulls = []
    for seed in range(40):
        d, t = synthetic(60, 6e-6, seed)
        fit = fit_speed_of_sound(d, t, intercept=True, distance_std_m=5e-4, tof_std_s=1e-7)
        pulls.append((fit.speed_of_sound_m_s - 343.2) / fit.speed_of_sound_std_m_s)
        assert fit.latency_s == pytest.approx(6e-6, abs=5 * fit.latency_std_s)
        assert fit.residual_rms_m == pytest.approx(5e-4, rel=0.3)
    assert np.std(pulls) == pytest.approx(1.0, abs=0.3)
    assert abs(np.mean(pulls)) < 0.5


def test_without_intercept_a_latency_biases_c():
    d, t = synthetic(60, 6e-6, 0)
    biased = fit_speed_of_sound(d, t)
    assert biased.latency_s == 0.0
    assert biased.speed_of_sound_m_s < 343.2 - 0.3  # ~0.5 m/s for 6 us at 0.4-2 m
    clean = fit_speed_of_sound(*synthetic(60, 0.0, 0))
    assert clean.speed_of_sound_m_s == pytest.approx(343.2, abs=4 * clean.speed_of_sound_std_m_s)


def test_nan_pairs_are_skipped_and_too_few_points_rejected():
    d, t = synthetic(10, 0.0, 1)
    t[3] = np.nan
    assert fit_speed_of_sound(d, t).n == 9
    with pytest.raises(ValueError):
        fit_speed_of_sound(d[:2], t[:2], intercept=True)
