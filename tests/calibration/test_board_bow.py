"""The board's bow out of its plane (calibration.camera.board_bow), from corners projected by
cv2.projectPoints off a sagged grid with Gaussian noise (no rendering needed)."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from calibration.camera.board_bow import BoardBow, CameraViews, estimate_bow, sagged_points
from calibration.camera.camera_calibration import CameraCalibration, calibrate_detections
from calibration.camera.corners import Checkerboard

from .synthetic import random_poses

BOARD = Checkerboard(6, 9, 0.03)
K = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 480.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.08, 0.05, 5e-4, -3e-4, 0.0])
NOISE_PX = 0.05


def _corners(sag_m: float, seed: int, n_view: int = 15) -> list[np.ndarray]:
    """The corners of `n_view` views of the board sagged by `sag_m`, `NOISE_PX` Gaussian
    noise per coordinate."""
    rng = np.random.default_rng(seed)
    rotvecs, translations = random_poses(n_view, rng, distance=(0.4, 0.7))
    obj = sagged_points(BOARD, sag_m)
    return [cv2.projectPoints(obj, r, t, K, DIST)[0].reshape(-1, 2)
            + NOISE_PX * rng.standard_normal((BOARD.n_corners, 2))
            for r, t in zip(rotvecs, translations, strict=True)]


def _views(sag_m: float, seed: int) -> CameraViews:
    """15 views of the board sagged by `sag_m`, started from intrinsics 0.1 % off."""
    return CameraViews(K * np.array([[1.001], [1.001], [1.0]]), 0.9 * DIST, (1280, 960),
                       _corners(sag_m, seed), NOISE_PX)


def _detections(sag_m: float, seed: int) -> dict:
    """The detections {(camera, step): (corners, size)} of camera 0's 15 views."""
    return {("cam0", f"pose/{k:04d}"): (c, (1280, 960))
            for k, c in enumerate(_corners(sag_m, seed))}


def test_the_sag_keeps_the_grids_corners_in_the_plane() -> None:
    points = sagged_points(BOARD, 2e-3)
    grid = points.reshape(BOARD.corners_y, BOARD.corners_x, 3)
    assert np.all(grid[[0, 0, -1, -1], [0, -1, 0, -1], 2] == pytest.approx(0.0, abs=1e-12))
    assert points[:, 2].max() == pytest.approx(2e-3, rel=0.05)  # the centre's, off the grid


@pytest.mark.parametrize(("sag_m", "seed"), [(0.0, 1), (1.5e-3, 2), (-3e-3, 3)])
def test_a_bow_is_recovered_within_its_std(sag_m: float, seed: int) -> None:
    """Flat, 1.5 mm and -3 mm over the 15 x 24 cm grid: within 3 std, the std 5-15 um (the
    corners' noise over the sag's effect on them), a flat board bounded by it."""
    bow = estimate_bow(BOARD, [_views(sag_m, seed)])
    assert 5e-6 < bow.std_m < 15e-6
    assert abs(bow.sag_m - sag_m) < 3 * bow.std_m
    assert bow.n_views == 15


def test_the_bows_std_is_the_bowed_boards_not_the_flat_fits() -> None:
    """The noise a bow is estimated with is the flat board's fit's, which the bow inflates:
    given twice the true noise, the same sag and the same std (the chi-square per degree of
    freedom at its minimum scales the curvature); the old std would double."""
    views = _views(5e-4, 4)
    honest = estimate_bow(BOARD, [views])
    inflated = estimate_bow(BOARD, [replace(views, sigma_px=2 * NOISE_PX)])
    assert inflated.sag_m == pytest.approx(honest.sag_m, rel=1e-9)
    assert inflated.std_m == pytest.approx(honest.std_m, rel=1e-6)


def test_the_board_points_are_sagged_where_the_bow_is_significant_only() -> None:
    """The board the cameras and the joint fit use: sagged where the bow is 3 std from 0, flat
    where it is not."""
    def points(sag_m: float, std_m: float) -> np.ndarray:
        cams = CameraCalibration(BOARD, {}, {}, {}, [], {}, bow=BoardBow(sag_m, std_m, 15))
        return cams.board_points()

    assert np.array_equal(points(2e-3, 1e-5), sagged_points(BOARD, 2e-3))
    assert np.array_equal(points(2e-5, 1e-5), BOARD.object_points())


def test_a_bowed_boards_cameras_are_calibrated_with_its_sag() -> None:
    """A 0.5 mm sag seen from 0.4-0.7 m (15 views, 0.05 px): the flat board's misfit, about
    twice the noise, would be taken for noise (and pull the focal length); calibrated again
    with the sagged corners, the corner noise is recovered within 10 % (its own scatter is
    2 %) and the focal length within 3 of its std, the views' poses fitted to those corners."""
    flat = calibrate_detections(_detections(5e-4, 4), ["cam0"], BOARD, fit_bow=False)
    assert flat.intrinsics["cam0"].noise.sigma_px > 1.5 * NOISE_PX  # what the sag costs
    cams = calibrate_detections(_detections(5e-4, 4), ["cam0"], BOARD)
    assert cams.bow is not None and cams.bow.significant
    intr = cams.intrinsics["cam0"]
    assert intr.noise.sigma_px == pytest.approx(NOISE_PX, rel=0.1)
    assert abs(intr.K[0, 0] - K[0, 0]) < 3 * intr.std[0]
    points = cams.board_points()
    assert np.array_equal(points, sagged_points(BOARD, cams.bow.sag_m))
    view = cams.views[("cam0", "pose/0000")]
    projected = cv2.projectPoints(points, view.rig_to_cam.transform.rotvec,
                                  view.rig_to_cam.transform.t, intr.K, intr.dist)[0]
    assert view.rms_px == pytest.approx(
        np.sqrt(np.mean(np.sum((view.corners_px - projected.reshape(-1, 2)) ** 2, axis=1))))


def test_a_flat_board_is_calibrated_once() -> None:
    """A flat board's bow is a bound, not modelled: the cameras are those of the flat fit, bit
    for bit (not calibrated again with a sag of noise)."""
    cams = calibrate_detections(_detections(0.0, 5), ["cam0"], BOARD)
    flat = calibrate_detections(_detections(0.0, 5), ["cam0"], BOARD, fit_bow=False)
    assert cams.bow is not None and not cams.bow.significant and flat.bow is None
    assert np.array_equal(cams.intrinsics["cam0"].K, flat.intrinsics["cam0"].K)
    assert np.array_equal(cams.board_points(), BOARD.object_points())
