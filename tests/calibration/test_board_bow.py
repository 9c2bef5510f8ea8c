"""The board's bow out of its plane (calibration.camera.board_bow), from corners projected by
cv2.projectPoints off a sagged grid with Gaussian noise (no rendering needed)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.camera.board_bow import BoardBow, CameraViews, estimate_bow, sagged_points
from calibration.camera.camera_calibration import CameraCalibration
from calibration.camera.corners import Checkerboard
from calibration.pipeline import _board_points

from .synthetic import random_poses

BOARD = Checkerboard(6, 9, 0.03)
K = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 480.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.08, 0.05, 5e-4, -3e-4, 0.0])
NOISE_PX = 0.05


def _views(sag_m: float, seed: int) -> CameraViews:
    """15 views of the board sagged by `sag_m`, started from intrinsics 0.1 % off."""
    rng = np.random.default_rng(seed)
    rotvecs, translations = random_poses(15, rng, distance=(0.4, 0.7))
    obj = sagged_points(BOARD, sag_m)
    corners = [cv2.projectPoints(obj, r, t, K, DIST)[0].reshape(-1, 2)
               + NOISE_PX * rng.standard_normal((BOARD.n_corners, 2))
               for r, t in zip(rotvecs, translations, strict=True)]
    return CameraViews(K * np.array([[1.001], [1.001], [1.0]]), 0.9 * DIST, (1280, 960),
                       corners, NOISE_PX)


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


def test_the_joint_fit_models_a_significant_bow_only() -> None:
    """The joint fit's board: sagged where the bow is 3 std from 0, flat where it is not."""
    def points(sag_m: float, std_m: float) -> np.ndarray:
        cams = CameraCalibration(BOARD, {}, {}, {}, [], {}, bow=BoardBow(sag_m, std_m, 15))
        return _board_points(cams)

    assert np.array_equal(points(2e-3, 1e-5), sagged_points(BOARD, 2e-3))
    assert np.array_equal(points(2e-5, 1e-5), BOARD.object_points())
