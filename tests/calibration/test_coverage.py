"""calibration.checks.coverage: errors drawn from a known covariance with a large common motion of
the array, as a session's cameras and scale give it."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.checks.coverage import COMMON_DOF, coverage, similarity_basis


def _world(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """72 microphones in a 0.1 m cloud, 5 um of independent error each and a common motion of
    8 um shifts, 50 urad turns and 50 ppm of scale; the covariance and its Cholesky factor."""
    rng = np.random.default_rng(seed)
    positions = 0.1 * rng.standard_normal((72, 3))
    common = similarity_basis(positions) * np.array([8e-6] * 3 + [5e-5] * 4)
    covariance = (5e-6) ** 2 * np.eye(216) + common @ common.T
    return positions, covariance, np.linalg.cholesky(covariance)


def test_similarity_basis_moves_the_points_as_a_rigid_scaled_body() -> None:
    rng = np.random.default_rng(0)
    p = rng.standard_normal((10, 3))
    turn_about_z = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 1e-6, 0.0])
    moved = (similarity_basis(p) @ turn_about_z).reshape(10, 3)
    centred = p - p.mean(axis=0)
    assert moved == pytest.approx(1e-6 * np.column_stack([-centred[:, 1], centred[:, 0],
                                                          np.zeros(10)]), abs=1e-15)
    assert (similarity_basis(p)[:, 6].reshape(10, 3)) == pytest.approx(centred)


@pytest.mark.slow
def test_a_right_covariance_covers_the_relative_geometry_in_every_session() -> None:
    """The plain share swings from session to session with the common draw; the common
    chi-square averages its 7 degrees of freedom and the relative share stays near 95 %."""
    positions, covariance, factor = _world(1)
    rng = np.random.default_rng(2)
    draws = [coverage((factor @ rng.standard_normal(216)).reshape(72, 3), covariance, positions)
             for _ in range(100)]
    plain = np.array([d.within_2_sigma for d in draws])
    relative = np.array([d.relative_within_2_sigma for d in draws])
    common = np.array([d.common_chi2 for d in draws])
    assert plain.min() < 0.8  # one session's plain share is a poor judge
    assert relative.min() > 0.85 and relative.mean() == pytest.approx(0.954, abs=0.02)
    assert common.mean() == pytest.approx(COMMON_DOF, rel=0.2)
    assert 0.3 < np.mean([d.common_p for d in draws]) < 0.7


@pytest.mark.slow
def test_a_covariance_half_as_wide_is_caught_both_ways() -> None:
    positions, covariance, factor = _world(3)
    rng = np.random.default_rng(4)
    draws = [coverage((factor @ rng.standard_normal(216)).reshape(72, 3), covariance / 4,
                      positions) for _ in range(20)]
    assert np.mean([d.relative_within_2_sigma for d in draws]) < 0.6
    assert np.mean([d.common_chi2 for d in draws]) > 20.0


def test_shapes_that_disagree_are_refused() -> None:
    with pytest.raises(ValueError, match="coverage needs"):
        coverage(np.zeros((4, 3)), np.eye(9), np.zeros((4, 3)))
