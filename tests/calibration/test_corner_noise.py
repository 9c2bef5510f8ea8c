"""The camera's corner noise estimated from its reprojection residuals
(calibration.camera.corner_noise, calibration.camera.camera_calibration): recovered from
corners projected by a known camera with Gaussian noise added, per view where a view is noisier, with the
degrees of freedom the fit absorbs; the rendered-image case is in test_cameras.py."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.camera.camera_calibration import calibrate_detections
from calibration.camera.corner_noise import estimate_corner_noise
from calibration.camera.corners import Checkerboard

from .synthetic import random_poses

BOARD = Checkerboard(6, 9, 0.03)
K = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 480.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.08, 0.05, 5e-4, -3e-4, 0.0])
NOISE_PX = 0.08


def _corners(n_view: int, seed: int, noise_px: np.ndarray) -> dict:
    """Detections {(camera, step): (corners, size)} of one camera: the board projected at
    `n_view` random poses, Gaussian noise of noise_px[k] per coordinate on view k."""
    rng = np.random.default_rng(seed)
    rotvecs, translations = random_poses(n_view, rng, distance=(0.4, 0.7))
    found = {}
    for k, (r, t) in enumerate(zip(rotvecs, translations, strict=True)):
        px = cv2.projectPoints(BOARD.object_points(), r, t, K, DIST)[0].reshape(-1, 2)
        found[("cam0", f"pose/{k:04d}")] = (px + noise_px[k] * rng.standard_normal(px.shape),
                                            (1280, 960))
    return found


def test_the_degrees_of_freedom_are_counted() -> None:
    """Sums of squares with the chi-square distribution of 2 n - p degrees of freedom give
    back the noise within 1 % (400 views); without the correction (p = 0) they would give it
    3 % low, as the plain RMS does."""
    rng = np.random.default_rng(1)
    n, absorbed = np.full(400, 54), np.full(400, 6.3)
    sums = NOISE_PX**2 * rng.chisquare(2 * n - absorbed)
    noise = estimate_corner_noise(sums, n, absorbed)
    assert noise.sigma_px == pytest.approx(NOISE_PX, rel=0.01)
    assert estimate_corner_noise(sums, n, np.zeros(400)).sigma_px < 0.98 * NOISE_PX
    assert noise.own.sum() <= 2  # views of the pooled noise flagged by chance: 1e-3 each


def test_a_cameras_noise_is_recovered_from_its_calibration() -> None:
    """20 views of 54 corners with 0.08 px per coordinate: the estimate within 5 % (its own
    scatter is 1.5 %), each view's shares of the 9 intrinsics summing to 9."""
    noise = calibrate_detections(_corners(20, 2, np.full(20, NOISE_PX)), ["cam0"],
                                 BOARD).intrinsics["cam0"].noise
    assert noise.sigma_px == pytest.approx(NOISE_PX, rel=0.05)
    assert noise.dof == pytest.approx(2 * 20 * 54 - 6 * 20 - 9)
    assert noise.std_px == pytest.approx(NOISE_PX / np.sqrt(2 * noise.dof), rel=0.05)


def test_a_noisier_view_gets_its_own_noise_and_weight() -> None:
    """One view of 20 with four times the noise (a blurred pose): it keeps its own estimate,
    the pool the others'. Against the same views with the same noise everywhere its pose's
    covariance grows: its own term 16-fold, the intrinsics' share (which dominates the
    translation and barely changes) not, so its rotation's by 3-4 (one noise for the camera,
    its pool 1.3 times wider, would give 1.75)."""
    sigmas = np.full(20, NOISE_PX)
    alike = calibrate_detections(_corners(20, 3, sigmas), ["cam0"], BOARD)
    sigmas[7] *= 4.0
    cams = calibrate_detections(_corners(20, 3, sigmas), ["cam0"], BOARD)
    noise = cams.intrinsics["cam0"].noise
    assert list(np.flatnonzero(noise.own)) == [7]
    assert noise.view_sigma_px[7] == pytest.approx(4 * NOISE_PX, rel=0.2)
    assert noise.sigma_px == pytest.approx(NOISE_PX, rel=0.05)
    view = cams.views[("cam0", "pose/0007")]
    assert view.sigma_px == noise.view_sigma_px[7]
    before = alike.views[("cam0", "pose/0007")].rig_to_cam.cov
    growth = np.diag(view.rig_to_cam.cov) / np.diag(before)
    assert np.all(growth[:3] > 2.5) and np.all(growth < 16)
