"""Microphone solver on synthetic scenes: efficiency against the bound and robustness.

Efficiency figures (mean error / mean joint CRLB of the same draws, same unknowns) are
Monte-Carlo estimates. With exact sources the 72 microphones' errors are nearly independent
and a handful of trials suffice; with source noise the errors are shared by all microphones
(mostly through the fitted latency), one trial is about one sample, and the per-trial mean
error spreads by ~50 %: 12 trials give a standard error of 0.10-0.15 on the ratio, hence the
1.45 tolerance there (the 1.1 target plus 2.5 standard errors). With 60 trials (seeds
100-159) the ratio measures 1.07 +- 0.07 at N = 96:
    PYTHONPATH=. .venv/bin/python -c "from tests.calibration.test_solver import efficiency;
    print(efficiency(16, 60, 5e-4))"
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from calibration.solve.crlb import expected_error_norm, joint_crlb
from calibration.solve.solver import (
    PriorGeometry,
    RigSources,
    SolverOptions,
    _Model,
    _Structure,
    rotated_point_jacobian,
    solve_microphones,
)
from calibration.solve.multilateration import multilaterate
from calibration.solve.paper_method import solve_paper_method
from tests.calibration.synthetic import C_TRUE, make_scene, mean_error

COMMON = SolverOptions(latency="common")
"""These scenes' times of flight are absolute (no reference board): one common latency."""


def efficiency(n_pose: int, trials: int, sigma_p: float) -> tuple[float, float]:
    """(mean error, mean error / mean joint bound) with c and a common latency fitted."""
    errors, bounds = [], []
    for seed in range(trials):
        scene = make_scene(n_pose, 100 + seed, sigma_t=1e-6, sigma_p=sigma_p)
        options = SolverOptions(
            latency="common",
            source_std_m=sigma_p if sigma_p else None,
            speed_of_sound_prior_std_m_s=None,
            latency_prior_std_s=None,
        )
        sol = solve_microphones(scene.measured_positions, scene.tof, 1e-6, options=options)
        errors.append(mean_error(sol.positions_m, scene.mics))
        bound = joint_crlb(scene.mics, scene.true_sources.positions(), C_TRUE, 1e-6,
                           latency="common", source_std_m=sigma_p)  # fmt: skip
        bounds.append(expected_error_norm(bound.mic_covariance_m2).mean())
    return float(np.mean(errors)), float(np.mean(errors) / np.mean(bounds))


@pytest.mark.parametrize("n_pose", [4, 16])
@pytest.mark.slow
def test_efficient_with_exact_sources(n_pose):
    _, ratio = efficiency(n_pose, trials=6, sigma_p=0.0)
    assert 0.85 < ratio < 1.15


@pytest.mark.parametrize("n_pose, target_m", [(4, 2.0e-3), (16, 1.2e-3)])
@pytest.mark.slow
def test_near_bound_with_noisy_sources(n_pose, target_m):
    """0.5 mm i.i.d. source noise, sources refined with that prior (24 and 96 sources).

    The issue's 2.0 / 1.0 mm targets are for the simulator's noise model; with i.i.d. source
    noise and a fitted latency the bound itself is 1.8 / 0.77 mm, so N = 96 gets 1.2 mm here.
    """
    mean, ratio = efficiency(n_pose, trials=12, sigma_p=5e-4)
    assert ratio < 1.45
    assert mean < target_m


def test_covariance_is_honest():
    scene = make_scene(8, 7, sigma_t=1e-6)
    sol = solve_microphones(scene.measured_positions, scene.tof, 1e-6, options=COMMON)
    predicted = expected_error_norm(sol.covariance_m2).mean()
    assert mean_error(sol.positions_m, scene.mics) == pytest.approx(predicted, rel=0.2)
    assert sol.chi2_per_dof == pytest.approx(1.0, abs=0.1)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.slow
def test_single_pose_has_no_mirror_or_divergence(seed):
    """6 coplanar sources: the camera-side rule keeps every microphone in front of the rig."""
    scene = make_scene(1, seed, sigma_t=1e-6, sigma_p=5e-4)
    rig = scene.true_sources
    normal = rig.positions()[[1, 2, 3]] - rig.positions()[0]
    normal = np.cross(normal[0], normal[1])
    side = lambda p: np.sign((p - rig.positions()[0]) @ normal)  # noqa: E731
    paper_c = SolverOptions(speed_of_sound_m_s=C_TRUE, fit_speed_of_sound=False, latency="none")
    fixed = solve_microphones(scene.measured_positions, scene.tof, 1e-6, options=paper_c)
    errors = np.linalg.norm(fixed.positions_m - scene.mics, axis=1)
    assert errors.max() < 15e-3 and errors.mean() < 5e-3
    free = solve_microphones(scene.measured_positions, scene.tof, 1e-6, options=COMMON)
    for positions in (fixed.positions_m, free.positions_m,
                      multilaterate(scene.measured_positions, C_TRUE * scene.tof)):  # fmt: skip
        assert np.all(side(positions) == side(np.zeros(3)))
    # c, a latency and the range are not separable from one pose: the priors bound the drift.
    assert np.linalg.norm(free.positions_m - scene.mics, axis=1).max() < 0.1


@pytest.mark.slow
def test_reflection_outliers_do_not_change_accuracy():
    clean = make_scene(16, 1, sigma_t=1e-6)
    dirty = make_scene(16, 1, sigma_t=1e-6, outlier_fraction=0.05)
    injected = dirty.tof - clean.tof > 1e-4
    ref = solve_microphones(clean.measured_positions, clean.tof, 1e-6, options=COMMON)
    sol = solve_microphones(dirty.measured_positions, dirty.tof, 1e-6, options=COMMON)
    assert np.array_equal(sol.outliers, injected)
    assert mean_error(sol.positions_m, dirty.mics) < 1.1 * mean_error(ref.positions_m, clean.mics)
    paper = solve_paper_method(
        dirty.measured_positions, dirty.tof, 1e-6, SolverOptions(speed_of_sound_m_s=C_TRUE)
    )
    assert mean_error(paper.positions_m, dirty.mics) > mean_error(sol.positions_m, dirty.mics)


def test_per_board_latency_and_speed_of_sound_recovered():
    latencies = (0.0, 20e-6, -15e-6, 5e-6)
    scene = make_scene(16, 2, sigma_t=1e-6, sigma_p=5e-4, latency_of_board=latencies)
    options = SolverOptions(latency="per_board", reference_board=0, source_std_m=5e-4)
    sol = solve_microphones(scene.measured_positions, scene.tof, 1e-6, scene.board_of_mic, options)
    err = sol.latency_s - np.array(latencies)
    assert err[0] == 0.0 and np.all(np.abs(err[1:]) < 4 * sol.latency_std_s[1:])
    assert np.all(np.abs(err) < 3e-6)  # the bound is ~2 us with 0.5 mm source noise
    assert abs(sol.speed_of_sound_m_s - C_TRUE) < 0.1
    assert abs(sol.speed_of_sound_m_s - C_TRUE) < 4 * sol.speed_of_sound_std_m_s


@pytest.mark.slow
def test_pose_refinement_removes_rigid_camera_errors():
    """Per-pose rigid errors of 2 mrad / 0.3 mm per axis (pessimistic fronto-parallel camera)."""
    scene = make_scene(16, 3, sigma_t=1e-6, pose_std=(2e-3, 3e-4))
    fixed = solve_microphones(scene.measured_positions, scene.tof, 1e-6, options=COMMON)
    refined = solve_microphones(scene.measured_sources, scene.tof, 1e-6,
                                options=replace(COMMON, refine_poses=True))  # fmt: skip
    assert mean_error(refined.positions_m, scene.mics) < 0.3 * mean_error(
        fixed.positions_m, scene.mics
    )
    truth = scene.true_sources.rotvec - scene.measured_sources.rotvec
    assert np.sqrt(np.mean((refined.pose_corrections[:, :3] - truth) ** 2)) < 0.5 * 2e-3


def test_prior_geometry_regularises_a_single_pose():
    scene = make_scene(1, 4, sigma_t=1e-6, sigma_p=5e-4)
    cad = scene.mics + np.array([0.3, -0.1, 0.2])  # the array in its own (shifted) frame
    options = SolverOptions(speed_of_sound_m_s=C_TRUE, fit_speed_of_sound=False, latency="none")
    direct = solve_microphones(scene.measured_positions, scene.tof, 1e-6, options=options)
    for prior in (PriorGeometry(cad), PriorGeometry(cad, deviation_std_m=1e-4)):
        sol = solve_microphones(scene.measured_positions, scene.tof, 1e-6, options=options,
                                prior_geometry=prior)  # fmt: skip
        assert mean_error(sol.positions_m, scene.mics) < 0.8 * mean_error(
            direct.positions_m, scene.mics
        )


def test_paper_method_is_not_better():
    scene = make_scene(4, 5, sigma_t=1e-6)
    options = SolverOptions(speed_of_sound_m_s=C_TRUE, fit_speed_of_sound=False, latency="none")
    ours = solve_microphones(scene.measured_positions, scene.tof, 1e-6, options=options)
    paper = solve_paper_method(scene.measured_positions, scene.tof, 1e-6, options)
    assert np.all(np.isfinite(paper.positions_m))
    assert mean_error(paper.positions_m, scene.mics) >= 0.99 * mean_error(
        ours.positions_m, scene.mics
    )


def test_analytic_jacobian_matches_finite_differences() -> None:
    scene = make_scene(2, 6, sigma_t=1e-6, pose_std=(1e-3, 1e-4))
    rig: RigSources = scene.measured_sources
    n_mic = scene.mics.shape[0]
    structure = _Structure(
        sources=rig, n_mic=n_mic, n_latency=2, fit_c=True, c_fixed=343.0,
        prior=PriorGeometry(scene.mics, deviation_std_m=1e-4), refine_poses=True,
        source_std_m=np.full(12, 5e-4), c_prior_std=1.0, latency_prior_std=1e-5,
    )  # fmt: skip
    src, mic = np.nonzero(np.ones(scene.tof.shape, bool))
    model = _Model(structure, scene.tof[src, mic], np.full(src.size, 1e-6), src, mic, mic % 3 - 1)
    rng = np.random.default_rng(0)
    x = 1e-3 * rng.standard_normal(model.n_params)
    x[model.offsets["c"]] = 343.0
    analytic = model.jacobian(x).toarray()
    numeric = np.empty_like(analytic)
    for j in range(model.n_params):
        h = 1e-7 * max(1.0, abs(x[j]))
        step = np.zeros_like(x)
        step[j] = h
        numeric[:, j] = (model.residuals(x + step) - model.residuals(x - step)) / (2 * h)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-4 * np.abs(analytic).max())


def test_rotated_point_jacobian():
    rng = np.random.default_rng(1)
    v, p = rng.standard_normal((5, 3)), rng.standard_normal((5, 3))
    from scipy.spatial.transform import Rotation

    numeric = np.stack(
        [(Rotation.from_rotvec(v + h).apply(p) - Rotation.from_rotvec(v - h).apply(p)) / 2e-7
         for h in 1e-7 * np.eye(3)], axis=-1)  # fmt: skip
    np.testing.assert_allclose(rotated_point_jacobian(v, p), numeric, atol=1e-6)


def test_multilateration_of_a_microphone_without_ranges_is_nan_without_a_warning() -> None:
    """A dead microphone's ranges are all missing: its position is NaN, the others' exact,
    and its empty set of residuals no numpy warning (the grid of issue 33 printed one)."""
    rng = np.random.default_rng(5)
    sources = rng.uniform(-0.5, 0.5, (12, 3)) + [0.0, 0.0, 1.0]
    mics = rng.uniform(-0.2, 0.2, (3, 3))
    ranges = np.linalg.norm(sources[:, None] - mics, axis=-1)
    ranges[:, 1] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        positions = multilaterate(sources, ranges)
    assert np.all(np.isnan(positions[1]))
    assert np.allclose(positions[[0, 2]], mics[[0, 2]], atol=1e-9)
