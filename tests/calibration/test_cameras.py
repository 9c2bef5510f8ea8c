"""calibration.camera.camera_calibration against the truth of a small simulated session (12 poses,
3 cameras).

Tolerances, and why: the simulated corners are found to about 0.04 px RMS, and with 13 views
calibrateCamera's own standard deviation of the focal length is about 0.03-0.04 % and of the
principal point about 0.3 px. The bounds below are about 4 of those sigmas (0.15 % focal,
2 px principal point), tight enough to catch a wrong corner order, a wrong pixel convention
(0.5 px) or a wrong distortion model, loose enough not to flake with the seed. Board poses:
0.2 degree and 1 mm (the focal-length error alone scales depth by ~0.03 % = 0.25 mm at 0.8 m).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.contracts.session import SessionReader
from calibration.camera.camera_calibration import (
    CameraCalibration,
    CameraCalibrationError,
    Checkerboard,
    calibrate_images,
    calibrate_session,
)
from calibration.camera.corners import detect_corners
from calibration.session_data import load_session

pytestmark = pytest.mark.slow  # every test here: the twelve-pose session and its camera calibration

CAMERAS = ["cam0", "cam1", "cam2"]


@pytest.fixture(scope="module")
def session(twelve_pose_session: Path) -> tuple[SessionReader, dict]:
    out = twelve_pose_session
    truth = json.loads(Path(out, "truth.json").read_text())
    return SessionReader(out), truth


@pytest.fixture(scope="module")
def calibration(session: tuple[SessionReader, dict]) -> CameraCalibration:
    return calibrate_session(session[0], _board(session[0]), CAMERAS)


def _board(reader: SessionReader) -> Checkerboard:
    return Checkerboard.of_rig(load_session(reader.path).rig)


def _rotation(rotvec: list[float]) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rotvec, dtype=np.float64))[0]


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(Ra.T @ Rb)[0])))


def _true_camera(truth: dict, name: str) -> dict:
    return next(c for c in truth["cameras"] if c["name"] == name)


def _true_pose_in_camera(truth: dict, camera: str, step: str) -> tuple[np.ndarray, np.ndarray]:
    """The true rig-to-camera R, t of a step's image."""
    if step == "refmic":
        pose = truth["reference_microphone"]["refmic_rig_to_cam0"]
    else:
        pose = truth["poses"][int(step.split("/")[1])]["rig_to_cam0"]
    ext = _true_camera(truth, camera)["from_cam0"]
    Ra, ta = _rotation(ext["rotvec"]), np.array(ext["t_m"])
    R, t = _rotation(pose["rotvec"]), np.array(pose["t_m"])
    return Ra @ R, Ra @ t + ta


def _board_in_view(truth: dict, camera: str, step: str, board: Checkerboard) -> bool:
    """True if every inner corner projects inside the image and the printed face is seen."""
    R, t = _true_pose_in_camera(truth, camera, step)
    cam = _true_camera(truth, camera)
    points = board.object_points() @ R.T + t
    if np.any(points[:, 2] <= 0) or R[:, 2] @ t >= 0:
        return False
    px, _ = cv2.projectPoints(
        points, np.zeros(3), np.zeros(3), np.array(cam["K"]), np.array(cam["dist"])
    )
    px = px.reshape(-1, 2)
    inside = (px >= 0) & (px <= np.array([cam["width"], cam["height"]]) - 1)
    return bool(np.all(inside))


def test_intrinsics_match_truth(calibration: CameraCalibration, session) -> None:
    _, truth = session
    for name, intr in calibration.intrinsics.items():
        K = np.array(_true_camera(truth, name)["K"])
        focal_error = np.abs(np.diag(intr.K)[:2] / np.diag(K)[:2] - 1)
        assert np.all(focal_error < 1.5e-3), (name, focal_error)
        assert np.all(np.abs(intr.K[:2, 2] - K[:2, 2]) < 2.0), (name, intr.K[:2, 2], K[:2, 2])
        assert intr.rms_px < 0.1
        assert intr.dist.shape == (5,) and intr.cov.shape == (9, 9)
        assert abs(intr.dist[0] - _true_camera(truth, name)["dist"][0]) < 0.005


def test_board_poses_match_truth_with_consistent_covariance(
    calibration: CameraCalibration, session
) -> None:
    _, truth = session
    for (camera, step), view in calibration.views.items():
        R, t = _true_pose_in_camera(truth, camera, step)
        assert _angle_deg(view.rig_to_cam.transform.R, R) < 0.2, (camera, step)
        error = view.rig_to_cam.transform.t - t
        assert np.linalg.norm(error) < 1e-3, (camera, step, error)
        std = np.sqrt(np.diag(view.rig_to_cam.cov)[3:])
        assert np.all(np.abs(error) < 5 * std), (camera, step, error, std)
        assert view.rms_px < 0.1


def test_corner_noise_matches_the_detected_corners_error(
    calibration: CameraCalibration, session
) -> None:
    """Each camera's corner noise estimated from its residuals (calibration.camera.corner_noise) is
    the scatter of its detected corners about the true projections, within 20 % (the
    rendered images' corners: about 0.006 px per coordinate)."""
    _, truth = session
    for name, intr in calibration.intrinsics.items():
        cam = _true_camera(truth, name)
        errors = []
        for (camera, step), view in calibration.views.items():
            if camera == name:
                R, t = _true_pose_in_camera(truth, camera, step)
                px, _ = cv2.projectPoints(calibration.board.object_points() @ R.T + t,
                                          np.zeros(3), np.zeros(3), np.array(cam["K"]),
                                          np.array(cam["dist"]))
                errors.append(view.corners_px - px.reshape(-1, 2))
        simulated = float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))
        assert intr.noise.sigma_px == pytest.approx(simulated, rel=0.2), name


def test_corners_are_in_rig_order(calibration: CameraCalibration, session) -> None:
    """Every view's corners lie on the true projections of the rig-frame corners, in order:
    a half-turn (speakers 1<->4 swapped) or a mirror would put them ~100 px away."""
    _, truth = session
    board = calibration.board
    for (camera, step), view in calibration.views.items():
        R, t = _true_pose_in_camera(truth, camera, step)
        cam = _true_camera(truth, camera)
        px, _ = cv2.projectPoints(
            board.object_points() @ R.T + t,
            np.zeros(3),
            np.zeros(3),
            np.array(cam["K"]),
            np.array(cam["dist"]),
        )
        error = np.linalg.norm(view.corners_px - px.reshape(-1, 2), axis=1)
        assert error.max() < 0.3, (camera, step, error.max())


def test_half_turned_image_keeps_rig_order(session) -> None:
    """The order does not depend on where OpenCV starts: rotate the image by 180 degrees and
    every rig corner must follow its own pixel."""
    reader, _ = session
    board = _board(reader)
    image = reader.read_image("pose/0000", "cam0.png")
    h, w = image.shape
    upright = detect_corners(image, board)
    turned = detect_corners(image[::-1, ::-1].copy(), board)
    assert upright is not None and turned is not None
    expected = np.array([w - 1, h - 1]) - upright
    assert np.abs(turned - expected).max() < 0.05


def test_images_without_board_are_reported_and_skipped(
    calibration: CameraCalibration, session
) -> None:
    reader, truth = session
    board = calibration.board
    images = {
        (c, s) for s, rec in reader.steps().items() for c in CAMERAS if f"{c}.png" in rec.files
    }
    missed = {(m.camera, m.step) for m in calibration.missed}
    visible = {(c, s) for c, s in images if _board_in_view(truth, c, s, board)}
    assert missed == images - visible
    assert missed, "the session should have images without the board"
    assert not missed & set(calibration.views)


def test_stereo_transforms_match_truth(calibration: CameraCalibration, session) -> None:
    _, truth = session
    assert calibration.reference_camera == "cam0"
    linked = [c for c in calibration.cam_from_cam0 if c != "cam0"]
    assert linked, "at least one camera should share views with cam0"
    for name in linked:
        ext = calibration.cam_from_cam0[name]
        true = _true_camera(truth, name)["from_cam0"]
        assert ext.n_shared_views >= 2
        assert _angle_deg(ext.cam0_to_cam.R, _rotation(true["rotvec"])) < 0.5
        assert np.linalg.norm(ext.cam0_to_cam.t - np.array(true["t_m"])) < 2e-3
        assert ext.rms_px < 0.1


def test_camera_with_too_few_views_is_left_out(calibration: CameraCalibration) -> None:
    """With 12 poses cam2 sees the board twice: too few for intrinsics, reported not raised."""
    assert "cam2" in calibration.uncalibrated
    views_per_camera = {c: sum(1 for cam, _ in calibration.views if cam == c) for c in CAMERAS}
    for camera, reason in calibration.uncalibrated.items():
        assert camera not in calibration.intrinsics and views_per_camera[camera] == 0
        assert "fewer than" in reason
    assert set(calibration.intrinsics) | set(calibration.uncalibrated) == set(CAMERAS)


def test_too_few_board_images_is_a_clear_error(session) -> None:
    reader, _ = session
    board = _board(reader)
    images = {("cam0", s): reader.read_image(s, "cam0.png") for s in ("pose/0000", "pose/0001")}
    images[("cam0", "blank")] = np.full((960, 1280), 90, np.uint8)
    with pytest.raises(CameraCalibrationError, match=r"cam0.*found in 2 of its images"):
        calibrate_images(images, ["cam0"], board)


def test_a_calibration_is_reproducible_to_the_last_bit(
        session: tuple[SessionReader, dict], calibration: CameraCalibration) -> None:
    """OpenCV's parallel sums in calibrateCamera once made the last bits differ from run to
    run, so no calibration could be compared across an interrupted capture."""
    again = calibrate_session(session[0], _board(session[0]), CAMERAS)
    for name, first in calibration.intrinsics.items():
        assert np.array_equal(first.K, again.intrinsics[name].K), name
        assert np.array_equal(first.dist, again.intrinsics[name].dist), name
    for name, extrinsics in calibration.cam_from_cam0.items():
        assert np.array_equal(extrinsics.cam0_to_cam.R,
                              again.cam_from_cam0[name].cam0_to_cam.R), name
