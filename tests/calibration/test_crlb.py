"""Bounds: E|e| of a Gaussian, per-mic bound vs the joint bound."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.solve.crlb import expected_error_norm, joint_crlb, mic_position_crlb
from tests.calibration.synthetic import C_TRUE, make_scene


def test_expected_error_norm_isotropic_and_degenerate():
    assert expected_error_norm(4.0 * np.eye(3)) == pytest.approx(2.0 * np.sqrt(8 / np.pi), rel=1e-6)
    # one axis only: E|z| sigma = sigma sqrt(2 / pi)
    assert expected_error_norm(np.diag([9.0, 0.0, 0.0])) == pytest.approx(
        3 * np.sqrt(2 / np.pi), rel=1e-4
    )
    rng = np.random.default_rng(0)
    cov = np.diag([1.0, 0.2, 0.01])
    samples = rng.multivariate_normal(np.zeros(3), cov, 200_000)
    assert expected_error_norm(cov) == pytest.approx(
        np.linalg.norm(samples, axis=1).mean(), rel=0.01
    )


def test_joint_bound_reduces_to_per_mic_bound_with_everything_known():
    scene = make_scene(4, 0)
    sources = scene.true_sources.positions()
    per_mic = mic_position_crlb(scene.mics, sources, C_TRUE, 1e-6)
    joint = joint_crlb(scene.mics, sources, C_TRUE, 1e-6, fit_speed_of_sound=False, latency="none")
    np.testing.assert_allclose(joint.mic_covariance_m2, per_mic, rtol=1e-8)
    # unknowns can only raise the bound; source noise raises it more when a latency is fitted
    free = joint_crlb(scene.mics, sources, C_TRUE, 1e-6, latency="common")
    noisy = joint_crlb(scene.mics, sources, C_TRUE, 1e-6, latency="common", source_std_m=5e-4)
    m = [
        expected_error_norm(b).mean()
        for b in (per_mic, free.mic_covariance_m2, noisy.mic_covariance_m2)
    ]
    assert m[0] < m[1] < m[2]
    assert 0 < free.speed_of_sound_std_m_s < noisy.speed_of_sound_std_m_s


def test_bound_matches_paper_table_c1_scale():
    """calibration-math.md C1: 1 us, exact sources, N = 24 gives about 0.59 mm (10 pose sets)."""
    values = [
        expected_error_norm(
            mic_position_crlb(s.mics, s.true_sources.positions(), C_TRUE, 1e-6)
        ).mean()
        for s in (make_scene(4, seed) for seed in range(10))
    ]
    assert np.mean(values) == pytest.approx(0.59e-3, rel=0.25)
