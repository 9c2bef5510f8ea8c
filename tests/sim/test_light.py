"""Tests of sim.light: rendered rig images must behave like photos for OpenCV's detector."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sim.geometry import CameraModel, Rig, RigidTransform, pinhole, rotation_from_rotvec
from sim.light import BACK_GREY, DARK_GREY, SPEAKER_GREY, WHITE_GREY, render_rig_image

FACING_CAMERA = np.diag([1.0, -1.0, -1.0])
"""Rig orientation (half-turn about X) whose printed face (+Z) looks back at camera 0."""
DETECTOR_FLAGS = (
    cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE + cv2.CALIB_CB_FAST_CHECK
)
"""OpenCV's default flags plus the fast check, which spares seconds on images without a board."""
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
MAX_CORNER_ERROR_PX = 0.2


def _pose(rig: Rig, rotvec: np.ndarray, centre_m: np.ndarray, base: np.ndarray) -> RigidTransform:
    """Rig pose with orientation rotation(rotvec) @ base and the pattern centre at centre_m."""
    R = rotation_from_rotvec(rotvec) @ base
    return RigidTransform(R, np.asarray(centre_m, dtype=np.float64) - R @ rig.centre())


def _random_facing_pose(rig: Rig, rng: np.random.Generator) -> RigidTransform:
    """Board 0.6-1.0 m in front of camera 0, tilted up to 40 deg, rolled up to 30 deg."""
    direction = rng.normal(size=2)
    tilt = direction / np.linalg.norm(direction) * np.deg2rad(rng.uniform(0.0, 40.0))
    roll = np.deg2rad(rng.uniform(-30.0, 30.0))
    centre = [rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), rng.uniform(0.6, 1.0)]
    return _pose(rig, np.array([tilt[0], tilt[1], roll]), np.array(centre), FACING_CAMERA)


def _detect_corners(image: np.ndarray, rig: Rig) -> np.ndarray | None:
    """Refined checkerboard corners (N, 2) in pixels, or None if the board is not found."""
    for size in [(rig.corners_x, rig.corners_y), (rig.corners_y, rig.corners_x)]:
        found, corners = cv2.findChessboardCorners(image, size, flags=DETECTOR_FLAGS)
        if found:
            refined = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1), SUBPIX_CRITERIA)
            return refined.reshape(-1, 2)
    return None


def _matched_errors(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Distance (pixels) from each true corner to its nearest detected corner.

    The detector may list corners reversed or transposed relative to rig.corner_points();
    the matching must then be one-to-one.
    """
    distances = np.linalg.norm(truth[:, None, :] - found[None, :, :], axis=2)
    nearest = distances.argmin(axis=1)
    assert len(np.unique(nearest)) == len(truth)
    return distances[np.arange(len(truth)), nearest]


@pytest.fixture(scope="module")
def camera() -> CameraModel:
    return pinhole("cam0")


@pytest.mark.parametrize(("seed", "noise_grey"), [(1, 0.0), (2, 2.0), (3, 2.0), (4, 2.0), (5, 2.0)])
def test_detected_corners_match_true_projection(
    camera: CameraModel, seed: int, noise_grey: float
) -> None:
    rig = Rig()
    rng = np.random.default_rng(seed)
    pose = _random_facing_pose(rig, rng)
    image = render_rig_image(camera, rig, pose, rng, noise_grey=noise_grey)

    found = _detect_corners(image, rig)

    assert found is not None
    truth = camera.project(pose.apply(rig.corner_points()))
    assert _matched_errors(found, truth).max() < MAX_CORNER_ERROR_PX


def test_corners_match_for_a_moved_camera_with_strong_distortion() -> None:
    """Distortion and camera pose are handled as cv2.projectPoints and cam0_to_cam define them."""
    rig = Rig()
    camera = pinhole(
        "cam1",
        focal_px=700.0,
        dist=(-0.3, 0.1, 0.002, -0.001, 0.0),
        cam0_to_cam=RigidTransform(rotation_from_rotvec(np.array([0.0, 0.1, 0.0])),
                                   np.array([-0.2, 0, 0])),
    )
    pose = _pose(rig, np.array([0.2, -0.3, 0.2]), np.array([0.2, 0.15, 0.6]), FACING_CAMERA)
    image = render_rig_image(camera, rig, pose, np.random.default_rng(6))

    found = _detect_corners(image, rig)

    assert found is not None
    truth = camera.project(pose.apply(rig.corner_points()))
    assert _matched_errors(found, truth).max() < MAX_CORNER_ERROR_PX


def test_no_board_is_found_in_an_empty_scene(camera: CameraModel) -> None:
    rig = Rig()
    image = render_rig_image(camera, rig, None, np.random.default_rng(7))

    assert _detect_corners(image, rig) is None
    found, _ = cv2.findChessboardCornersSB(image, (rig.corners_x, rig.corners_y))
    assert not found


def test_back_of_the_plate_shows_no_pattern(camera: CameraModel) -> None:
    rig = Rig()
    back_facing = _pose(rig, np.array([0.2, -0.1, 0.3]), np.array([0.0, 0.0, 0.8]), np.eye(3))
    image = render_rig_image(camera, rig, back_facing, np.random.default_rng(8), noise_grey=0)

    assert _detect_corners(image, rig) is None
    hull = cv2.convexHull(camera.project(back_facing.apply(rig.corner_points())).astype(np.int32))
    inside = np.zeros(image.shape, dtype=np.uint8)
    cv2.fillConvexPoly(inside, hull, 1)
    assert np.all(image[inside == 1] == round(BACK_GREY))


def test_output_is_grey_uint8_of_the_camera_size() -> None:
    camera = pinhole("cam2", width=640, height=480, focal_px=500.0)
    pose = _pose(Rig(), np.zeros(3), np.array([0.0, 0.0, 0.9]), FACING_CAMERA)

    image = render_rig_image(camera, Rig(), pose, np.random.default_rng(9))

    assert image.dtype == np.uint8
    assert image.shape == (480, 640)


@pytest.fixture(scope="module")
def fronto_parallel() -> tuple[CameraModel, Rig, RigidTransform, np.ndarray]:
    """A sharp, noise-free, undistorted view of the board square-on, 0.8 m away, with the
    pattern centre off the pixel grid so that edges fall between pixel centres."""
    camera = pinhole("ideal", dist=(0.0, 0.0, 0.0, 0.0, 0.0))
    rig = Rig()
    pose = _pose(rig, np.zeros(3), np.array([0.01234, -0.00567, 0.8]), FACING_CAMERA)
    image = render_rig_image(
        camera, rig, pose, np.random.default_rng(10), noise_grey=0.0, blur_sigma_px=0.0
    )
    return camera, rig, pose, image


def test_edges_are_area_filtered(
    fronto_parallel: tuple[CameraModel, Rig, RigidTransform, np.ndarray],
) -> None:
    """Across a vertical edge, the summed dark fraction of the pixels places the edge at its
    true projection, as only a per-pixel area (box) filter does; point sampling would be off
    by up to half a pixel."""
    camera, rig, pose, image = fronto_parallel
    s = rig.square_m
    # Edge X = s between dark square (0, 0) on its left (in the image) and white square (1, 0).
    edge_u, row_v = camera.project(pose.apply(np.array([[s, 0.5 * s, 0.0]])))[0]
    left = camera.project(pose.apply(np.array([[0.5 * s, 0.5 * s, 0.0]])))[0, 0]
    right = camera.project(pose.apply(np.array([[1.5 * s, 0.5 * s, 0.0]])))[0, 0]
    columns = np.arange(round(left), round(right) + 1)
    row = image[round(row_v), columns].astype(np.float64)
    dark_fraction = (WHITE_GREY - row) / (WHITE_GREY - DARK_GREY)

    measured_edge_u = columns[0] - 0.5 + dark_fraction.sum()

    assert abs(measured_edge_u - edge_u) < 0.02


def test_square_parity_and_speakers_are_as_documented(
    fronto_parallel: tuple[CameraModel, Rig, RigidTransform, np.ndarray],
) -> None:
    """Square (i, j) is dark when i + j is even; the speakers are mid-grey discs."""
    camera, rig, pose, image = fronto_parallel
    s = rig.square_m
    squares = [(-1, -1), (0, 0), (rig.corners_x - 1, -1), (-1, rig.corners_y - 1), (0, 1)]
    centres = np.array([[(i + 0.5) * s, (j + 0.5) * s, 0.0] for i, j in squares])
    speakers = rig.speakers_m * np.array([1.0, 1.0, 0.0])
    points = camera.project(pose.apply(np.vstack([centres, speakers])))
    grey = image[np.rint(points[:, 1]).astype(int), np.rint(points[:, 0]).astype(int)]

    dark, white = round(DARK_GREY), round(WHITE_GREY)
    assert grey[: len(squares)].tolist() == [dark, dark, dark, white, white]
    assert np.all(grey[len(squares) :] == round(SPEAKER_GREY))
