"""calibration.camera.recovered_views: the corners of a view that no detector found (a
highlight over the board, an arm in front of it), fitted again where the rig's placed pose
predicts them.

Images are sim.light's renders of the rig square-on at 0.75 m (about 40 px squares) with 2
grey levels of noise, the highlight and the arm drawn by the simulated mistakes' own models
(sim.mistakes.images), and the predicted pose 1.5 px off in the image, as the times of flight
place a rig on the realistic lab (0.6-1.0 px).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.camera.camera_calibration import CameraIntrinsics
from calibration.camera.corner_noise import CornerNoise
from calibration.camera.corners import Checkerboard, detect_corners
from calibration.camera.recovered_views import (
    GLARE_CLEARANCE_SQUARES,
    SATURATED_GREY,
    recover_view,
)
from sim.geometry import Rig, RigidTransform, pinhole
from sim.light import render_rig_image
from sim.mistakes.images import Glare, Occluder
from sim.poses import FACING_CAMERA

RIG = Rig()
BOARD = Checkerboard(RIG.corners_x, RIG.corners_y, RIG.square_m)
CAMERA = pinhole("cam0")
SIGMA_PX = 0.006
"""The corner fit's noise at 2 grey levels (tests/calibration/test_corner_accuracy.py)."""
STEP = "pose/0004"


def _intrinsics() -> CameraIntrinsics:
    """The true camera, as a calibration of it would hand it over."""
    noise = CornerNoise(SIGMA_PX, 540, 1000.0, np.array([SIGMA_PX]), np.array([False]))
    return CameraIntrinsics("cam0", CAMERA.width, CAMERA.height, CAMERA.K,
                            np.asarray(CAMERA.dist, dtype=float), np.zeros((9, 9)),
                            SIGMA_PX, 10, noise)


def _pose(shift_px: tuple[float, float] = (0.0, 0.0)) -> RigidTransform:
    """The rig square-on at 0.75 m, slightly turned; `shift_px` moves it across the image."""
    depth = 0.75
    turn = cv2.Rodrigues(np.array([0.15, -0.2, 0.1]))[0]
    R = turn @ FACING_CAMERA
    centre = np.array([0.02 + shift_px[0] * depth / CAMERA.K[0, 0],
                       -0.01 + shift_px[1] * depth / CAMERA.K[1, 1], depth])
    return RigidTransform(R, centre - R @ RIG.centre())


def _render(scene=None) -> tuple[np.ndarray, np.ndarray]:
    """(image, true corners (n, 2) px) of the rig at `_pose`, with a scene mistake."""
    pose = _pose()
    image = render_rig_image(CAMERA, RIG, pose, np.random.default_rng(7), 2.0, scene=scene)
    return image, CAMERA.project(pose.apply(RIG.corner_points()))


def _recovered(image: np.ndarray):
    return recover_view(image, BOARD, BOARD.object_points(), _intrinsics(), STEP,
                        _pose((1.5, -1.0)))


def test_a_whole_board_comes_back_as_the_detector_finds_it() -> None:
    """From a prediction 1.5 px off, every corner of a clean image is refitted to where the
    detector's own refinement puts it."""
    image, _ = _render()
    found = _recovered(image)
    detected = detect_corners(image, BOARD)
    assert found is not None and detected is not None
    assert found.kept == BOARD.n_corners and found.near_glare == 0
    np.testing.assert_allclose(found.view.corners_px, detected, atol=1e-4)
    assert found.view.step == STEP and found.view.sigma_px == SIGMA_PX


def test_corners_near_a_highlight_are_left_out_and_the_rest_are_true() -> None:
    """A highlight of the glare mistake's model saturating 40 px around a corner: no
    detector finds that board. Its corners within `GLARE_CLEARANCE_SQUARES` of a saturated
    pixel (a pixel's rounding allowed) are left out, every corner in the highlight among
    them; the others lie within the
    fit's noise of the truth (3 sigma at most here; the bound is 5)."""
    clean, truth = _render()
    centre = truth[BOARD.corners_x * 4 + 2] + np.array([9.0, -6.0])
    image, _ = _render(Glare((float(centre[0]), float(centre[1])), 40.0))
    assert detect_corners(image, BOARD) is None
    found = _recovered(image)
    assert found is not None
    kept = np.isfinite(found.view.corners_px).all(axis=1)
    in_glare = np.linalg.norm(truth - centre, axis=1) < 40.0
    assert in_glare.sum() >= 2 and not kept[in_glare].any()
    assert found.near_glare >= in_glare.sum()
    saturated = np.argwhere(image >= SATURATED_GREY)[:, ::-1]
    clearance = np.linalg.norm(found.view.corners_px[kept, None] - saturated[None], axis=2)
    square_px = np.median(np.linalg.norm(np.diff(truth.reshape(9, 6, 2), axis=1), axis=2))
    assert clearance.min() >= GLARE_CLEARANCE_SQUARES * square_px - 1.0
    assert found.kept == kept.sum() >= BOARD.n_corners // 3
    error = np.linalg.norm(found.view.corners_px[kept] - truth[kept], axis=1)
    assert error.max() < 5 * SIGMA_PX * np.sqrt(2)


@pytest.mark.parametrize(("reach", "half_width_px", "recovered"),
                         [(0.4, 45.0, True), (0.9, 120.0, False)])
def test_corners_under_an_arm_are_left_out_and_a_board_mostly_hidden_is_not_used(
        reach: float, half_width_px: float, recovered: bool) -> None:
    """An arm of the hidden-board mistake's model over part of the board (9 corners): the
    corners it hides are not kept (their fit fails, no contrast), the others are true to the
    noise (3 sigma at most here). An arm over 38 of the 54 leaves fewer than a quarter of
    them to keep (those at its edge fail too), and no view."""
    _, truth = _render()
    low, high = truth.min(axis=0), truth.max(axis=0)
    hand = (low[0] + reach * (high[0] - low[0]), float(truth[:, 1].mean()))
    arm = Occluder(hand, (-1.0, 0.0), half_width_px, half_width_px + 10.0)
    image, _ = _render(arm)
    hidden = arm.covers(truth)
    assert hidden.any()
    found = _recovered(image)
    if not recovered:
        assert found is None
        return
    assert found is not None
    kept = np.isfinite(found.view.corners_px).all(axis=1)
    assert not kept[hidden].any() and kept.sum() >= BOARD.n_corners // 2
    error = np.linalg.norm(found.view.corners_px[kept] - truth[kept], axis=1)
    assert error.max() < 5 * SIGMA_PX * np.sqrt(2)


def test_a_board_behind_the_camera_is_not_predicted() -> None:
    image, _ = _render()
    behind = RigidTransform(FACING_CAMERA, np.array([0.0, 0.0, -0.5]))
    assert recover_view(image, BOARD, BOARD.object_points(), _intrinsics(), STEP,
                        behind) is None


def test_a_board_running_off_the_image_keeps_the_corners_inside() -> None:
    """The rig predicted half out of the image (as another camera's pose puts it): the
    corners predicted outside are not refined, those well inside are kept and true."""
    shifted = _pose((-660.0, 0.0))
    image = render_rig_image(CAMERA, RIG, shifted, np.random.default_rng(3), 2.0)
    truth = CAMERA.project(shifted.apply(RIG.corner_points()))
    nudged = RigidTransform(shifted.R, shifted.t + np.array([1.2, -0.8, 0.0]) * 0.75 / 1000)
    found = recover_view(image, BOARD, BOARD.object_points(), _intrinsics(), STEP, nudged)
    outside = truth[:, 0] < 0
    assert outside.sum() >= 6 and found is not None
    kept = np.isfinite(found.view.corners_px).all(axis=1)
    assert not kept[outside].any() and kept.sum() >= BOARD.n_corners // 3
    error = np.linalg.norm(found.view.corners_px[kept] - truth[kept], axis=1)
    assert error.max() < 5 * SIGMA_PX * np.sqrt(2)


def test_a_view_whose_pose_does_not_fit_is_not_used_and_refuses_nothing(monkeypatch) -> None:
    """Where no pose fits the kept corners (solvePnP fails), the view is simply not
    recovered: the session is not refused for it."""
    import calibration.camera.camera_calibration as camera_calibration

    image, _ = _render()
    monkeypatch.setattr(camera_calibration.cv2, "solvePnP",
                        lambda *args, **kwargs: (False, None, None))
    assert _recovered(image) is None
