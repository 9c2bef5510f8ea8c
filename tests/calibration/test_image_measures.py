"""calibration.camera.image_measures' X-corners (the board's inner corners count, the
corners of its outer squares on the white margin and an arm's edge across the squares do
not), its JPEG detector, and a board too blurred to be found (calibration.camera.image_checks)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calibration.camera.corners import Checkerboard
from calibration.camera.image_checks import MJPEG_QUANTISATION, ViewImage, check_images
from calibration.camera.image_measures import jpeg_quantisation, x_corner_response, x_corners

SQUARE_PX = 30
ORIGIN_PX = 100


def _board(squares: int = 5, arm: bool = False) -> np.ndarray:
    """A `squares` x `squares` checkerboard of dark (40) and light (210) squares on a light
    margin in a 400 x 400 image with 2 grey levels of noise; with `arm`, a mid-grey (90) band
    over the right half of the board's lower rows."""
    v, u = np.mgrid[0:400, 0:400]
    i, j = (u - ORIGIN_PX) // SQUARE_PX, (v - ORIGIN_PX) // SQUARE_PX
    on_board = (i >= 0) & (i < squares) & (j >= 0) & (j < squares)
    image = np.where(on_board & ((i + j) % 2 == 0), 40.0, 210.0)
    if arm:
        image[ORIGIN_PX + 3 * SQUARE_PX - 7:, ORIGIN_PX + 2 * SQUARE_PX + 9:] = 90.0
    noisy = image + np.random.default_rng(0).normal(0.0, 2.0, image.shape)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8)


def _inner_corners(squares: int) -> set[tuple[int, int]]:
    return {(ORIGIN_PX + a * SQUARE_PX, ORIGIN_PX + b * SQUARE_PX)
            for a in range(1, squares) for b in range(1, squares)}


def _found(image: np.ndarray) -> set[tuple[int, ...]]:
    inner = np.array(sorted(_inner_corners(5)))
    response = x_corner_response(image)
    level = 0.3 * float(np.median(response[inner[:, 1], inner[:, 0]]))
    found = x_corners(image, level, SQUARE_PX)
    # snap each to the nearest inner corner when within 2 px, else keep it as it is
    snapped = set()
    for point in found:
        nearest = inner[np.argmin(np.linalg.norm(inner - point, axis=1))]
        close = np.linalg.norm(nearest - point) <= 2.0
        snapped.add(tuple(int(x) for x in (nearest if close else np.round(point))))
    return snapped


def test_the_inner_corners_count_and_the_margins_l_corners_do_not() -> None:
    assert _found(_board()) == _inner_corners(5)


def test_an_arms_edge_across_the_squares_makes_no_corner() -> None:
    covered = {(x, y) for x, y in _inner_corners(5)
               if y >= ORIGIN_PX + 3 * SQUARE_PX - 7 and x >= ORIGIN_PX + 2 * SQUARE_PX + 9}
    assert covered
    assert _found(_board(arm=True)) == _inner_corners(5) - covered


@pytest.mark.parametrize("noise_grey", [2.0, 10.0])
def test_jpeg_is_told_from_raw_frames_however_noisy(noise_grey: float) -> None:
    """The quantised DCT shows JPEG at the qualities webcams use, under the ideal world's
    noise and under one as strong as the realistic lab's camera at gain 16 (where block
    seams had vanished); raw frames, noisy or not, stay near 0. (A frame whose every block
    JPEG flattens, no noise on a flat field, shows nothing, and has no corner to move.)"""
    rng = np.random.default_rng(1)
    scene = cv2.resize(_board().astype(np.float64), (640, 480))
    raw = np.clip(np.round(scene + rng.normal(0.0, noise_grey, scene.shape)), 0, 255)
    raw = raw.astype(np.uint8)
    assert jpeg_quantisation(raw) < 0.5 * MJPEG_QUANTISATION
    for quality in (70, 90, 95):
        ok, encoded = cv2.imencode(".jpg", raw, [cv2.IMWRITE_JPEG_QUALITY, quality])
        assert ok
        decoded = cv2.imdecode(encoded, cv2.IMREAD_GRAYSCALE)
        assert decoded is not None
        assert jpeg_quantisation(decoded) > 1.5 * MJPEG_QUANTISATION, quality


def _motion_blurred(image: np.ndarray, length_px: int, highlight: bool) -> np.ndarray:
    """`image` smeared along its rows over `length_px` (a motion during the exposure), with a
    saturated disc of 25 px radius on the board's centre when `highlight`."""
    smeared = cv2.filter2D(image.astype(np.float32), -1,
                           np.full((1, length_px), 1.0 / length_px, np.float32))
    if highlight:
        centre = ORIGIN_PX + 5 * SQUARE_PX // 2
        cv2.circle(smeared, (centre, centre), 25, 255.0, -1)
    return np.clip(np.round(smeared), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("highlight", [True, False])
def test_a_board_too_blurred_to_be_found_is_named_with_its_glare(highlight: bool) -> None:
    """Three sharp views of a camera and one whose board was not found: smeared over a third
    of a square, its corners respond too weakly to count as visible, but enough of them show
    to name the blur (and the highlight on them). Unnamed before: 'no board in view'."""
    board = Checkerboard(corners_x=4, corners_y=4, square_m=0.03)
    corners = np.array([(ORIGIN_PX + a * SQUARE_PX, ORIGIN_PX + b * SQUARE_PX)
                        for b in range(1, 5) for a in range(1, 5)], dtype=float)
    sharp = _board()
    images = {("cam0", f"pose/{k:04d}"): sharp for k in range(3)}
    images[("cam0", "pose/0003")] = _motion_blurred(sharp, 11, highlight)
    views = [ViewImage("cam0", step, corners if step != "pose/0003" else None)
             for _, step in images]
    verdict = check_images(views, images.__getitem__, board)
    kinds = ["motion-blur", "glare"] if highlight else ["motion-blur"]
    assert [f.kind for f in verdict.findings] == kinds
    assert all(f.poses == ["pose/0003"] and f.cameras == ["cam0"] for f in verdict.findings)
    assert verdict.left_out == {("cam0", "pose/0003"): " and ".join(
        k.replace("-", " ") for k in kinds)}


@pytest.mark.parametrize("arm", [False, True])
def test_a_board_in_glare_is_named_hidden_only_when_more_is_missing_than_the_glare_hides(
        arm: bool) -> None:
    """A board of 49 inner corners not found, with a highlight on it: the corners within a
    square of the highlight count as seen, so a highlight alone is named glare only; with an
    arm over 25 of the corners as well, both are named. (Only the glare was named when both
    fell on one image: seed 4 of every pair on the 20-pose realistic sessions.)"""
    board = Checkerboard(corners_x=7, corners_y=7, square_m=0.03)
    corners = np.array([(ORIGIN_PX + a * SQUARE_PX, ORIGIN_PX + b * SQUARE_PX)
                        for b in range(1, 8) for a in range(1, 8)], dtype=float)
    sharp = _board(squares=8)
    spoiled = _board(squares=8, arm=arm)
    cv2.circle(spoiled, (ORIGIN_PX + 3 * SQUARE_PX // 2, ORIGIN_PX + 3 * SQUARE_PX // 2), 25,
               255, -1)
    images = {("cam0", f"pose/{k:04d}"): sharp for k in range(3)}
    images[("cam0", "pose/0003")] = spoiled
    views = [ViewImage("cam0", step, corners if step != "pose/0003" else None)
             for _, step in images]
    verdict = check_images(views, images.__getitem__, board)
    kinds = ["glare", "hidden-board"] if arm else ["glare"]
    assert [f.kind for f in verdict.findings] == kinds
    assert verdict.left_out == {("cam0", "pose/0003"): " and ".join(
        k.replace("-", " ") for k in kinds)}
