"""The board's colour convention, its marker, and known intrinsics in the camera stage.

Images are rendered by sim.light from a pose chosen here; the truth is the projection of the
rig's inner corners in rig order (X fastest)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from acquisition.contracts.rig_description import KnownIntrinsics
from calibration.camera.camera_calibration import calibrate_images
from calibration.camera.corners import Checkerboard, detect_corners
from sim.geometry import Rig, RigidTransform, pinhole
from sim.light import DARK_GREY, WHITE_GREY, render_rig_image
from sim.poses import FACING_CAMERA

CAMERA = pinhole("cam0")


def _pose(tilt: tuple[float, float, float], depth: float, rig: Rig,
          half_turn: bool = False) -> RigidTransform:
    """The rig facing the camera, tilted, its pattern centre at `depth` on the optical axis;
    `half_turn` turns it by 180 degrees about its normal through that centre."""
    R = cv2.Rodrigues(np.array(tilt))[0] @ FACING_CAMERA
    if half_turn:
        R = R @ np.diag([-1.0, -1.0, 1.0])
    return RigidTransform(R, np.array([0.0, 0.0, depth]) - R @ rig.centre())


def _true_corners(rig: Rig, pose: RigidTransform) -> np.ndarray:
    return CAMERA.project(pose.apply(rig.corner_points()))


def _image(rig: Rig, pose: RigidTransform, marker: tuple[int, int] | None = None) -> np.ndarray:
    image = render_rig_image(CAMERA, rig, pose, np.random.default_rng(1))
    if marker is not None:  # a round dot of the other colour at the marker square's centre
        i, j = marker
        centre = CAMERA.project(pose.apply(np.array([[(i + 0.5) * rig.square_m,
                                                      (j + 0.5) * rig.square_m, 0.0]])))[0]
        dark = ((i + j) % 2 == 0) == (rig.origin_square == "dark")
        cv2.circle(image, tuple(int(v) for v in np.rint(centre)), 8,
                   int(WHITE_GREY if dark else DARK_GREY), -1, lineType=cv2.LINE_AA)
    return image


@pytest.mark.parametrize("origin", ["dark", "light"])
def test_the_stated_colour_puts_the_origin_where_it_is_printed(origin: str) -> None:
    rig = Rig(origin_square=origin)  # type: ignore[arg-type]
    pose = _pose((0.3, -0.2, 0.1), 0.7, rig)
    truth = _true_corners(rig, pose)
    right = Checkerboard(6, 9, 0.03, origin_dark=origin == "dark")
    wrong = Checkerboard(6, 9, 0.03, origin_dark=origin != "dark")
    found = detect_corners(_image(rig, pose), right)
    assert found is not None and np.abs(found - truth).max() < 0.3
    turned = detect_corners(_image(rig, pose), wrong)  # the other convention: half a turn
    assert turned is not None and np.abs(turned - truth[::-1]).max() < 0.3


@pytest.mark.parametrize("half_turn", [False, True])
def test_a_marker_resolves_a_board_that_looks_the_same_turned(half_turn: bool) -> None:
    rig = Rig(corners_x=6, corners_y=8)  # 7 x 9 squares: the same colours after a half-turn
    board = Checkerboard(6, 8, 0.03, marker_square=(1, 2))
    pose = _pose((0.25, 0.2, -0.3), 0.65, rig, half_turn)
    found = detect_corners(_image(rig, pose, marker=(1, 2)), board)
    assert found is not None
    assert np.abs(found - _true_corners(rig, pose)).max() < 0.3


def _views(rig: Rig, n: int) -> dict[tuple[str, str], np.ndarray]:
    tilts = [(0.35, 0.1, 0.0), (-0.3, 0.2, 0.3), (0.1, -0.4, -0.2), (0.2, 0.3, 0.5),
             (-0.2, -0.3, 0.1), (0.4, -0.1, -0.4)]
    return {("cam0", f"pose/{k:04d}"): _image(rig, _pose(tilts[k], 0.6 + 0.05 * k, rig))
            for k in range(n)}


def _known(use: str, K: np.ndarray, std: list[float] | None = None) -> KnownIntrinsics:
    return KnownIntrinsics(use=use, camera_matrix=tuple(map(tuple, K)),  # type: ignore[arg-type]
                           distortion=tuple(CAMERA.dist), std=std)  # type: ignore[arg-type]


def test_fixed_intrinsics_are_used_as_given_even_with_one_view() -> None:
    rig = Rig()
    board = Checkerboard(6, 9, 0.03)
    K = CAMERA.K * np.array([[1.001], [1.001], [1.0]])  # 0.1 % off, held exactly
    cal = calibrate_images(_views(rig, 1), ["cam0"], board,
                           known={"cam0": _known("fixed", K)})
    assert np.array_equal(cal.intrinsics["cam0"].K, K)
    assert np.all(cal.intrinsics["cam0"].cov == 0)
    view = cal.views[("cam0", "pose/0000")]
    assert view.rms_px < 0.3 and np.all(np.isfinite(view.rig_to_cam.cov))


@pytest.mark.slow
def test_a_prior_is_weighed_against_the_images() -> None:
    rig = Rig()
    board = Checkerboard(6, 9, 0.03)
    views = _views(rig, 6)
    free = calibrate_images(views, ["cam0"], board).intrinsics["cam0"]
    K_prior = CAMERA.K.copy()
    K_prior[0, 0] = K_prior[1, 1] = CAMERA.K[0, 0] + 5.0  # 5 px off the truth
    std = [0.5, 0.5, 0.5, 0.5, 0.01, 0.05, 1e-3, 1e-3, 0.1]
    cal = calibrate_images(views, ["cam0"], board, known={"cam0": _known("prior", K_prior, std)})
    combined = cal.intrinsics["cam0"]
    fx_free, fx_prior, fx = free.K[0, 0], K_prior[0, 0], combined.K[0, 0]
    assert min(fx_free, fx_prior) < fx < max(fx_free, fx_prior)  # between the two
    assert combined.std[0] < min(free.std[0], 0.5)  # better known than either alone


@pytest.mark.slow
def test_the_robust_detector_skips_a_board_that_another_camera_shows_running_off_the_image(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A board cut by the image's edge passes the fast check and fails the classic detector;
    the robust one would spend 0.1-0.4 s failing on it. Where another camera saw the whole
    board at the same step, the cut is predicted and the robust detector is not run; where
    no other camera saw it, it still is."""
    import calibration.camera.camera_calibration as stage
    from calibration.camera.corners import Unsure, detect_corners_quickly

    rig, board = Rig(), Checkerboard(6, 9, 0.03)
    cam1 = pinhole("cam1", cam0_to_cam=RigidTransform(  # turned: the board sits further left
        cv2.Rodrigues(np.array([0.0, -0.3, 0.0]))[0], np.zeros(3)))
    tilts = [(0.35, 0.1, 0.0), (-0.3, 0.2, 0.3), (0.1, -0.4, -0.2), (0.2, 0.3, 0.5),
             (-0.2, -0.3, 0.1), (0.4, -0.1, -0.4)]
    poses = {f"pose/{k:04d}": _pose(t, 0.7 + 0.05 * k, rig) for k, t in enumerate(tilts)}
    side = _pose((0.1, 0.2, 0.0), 0.6, rig)  # moved left: whole in cam0, 100 px off cam1
    poses["pose/0006"] = RigidTransform(side.R, side.t + np.array([-0.15, 0.0, 0.0]))
    rng = np.random.default_rng(2)
    images = {(cam.name, step): render_rig_image(cam, rig, pose, rng)
              for step, pose in poses.items() for cam in (CAMERA, cam1)}
    # the same cut board at a step where camera 0 saw nothing: no prediction possible
    images[("cam0", "pose/0007")] = render_rig_image(CAMERA, rig, None, rng)
    images[("cam1", "pose/0007")] = images[("cam1", "pose/0006")].copy()
    cut = [("cam1", "pose/0006"), ("cam1", "pose/0007")]
    assert all(isinstance(detect_corners_quickly(images[k], board), Unsure) for k in cut)
    assert detect_corners(images[("cam0", "pose/0006")], board) is not None

    robust_calls = []
    robustly = stage.detect_corners_robustly

    def counted(image: np.ndarray, b: Checkerboard) -> np.ndarray | None:
        robust_calls.append(next(k for k, v in images.items() if v is image))
        return robustly(image, b)

    monkeypatch.setattr(stage, "detect_corners_robustly", counted)
    cal = calibrate_images(images, ["cam0", "cam1"], board)
    assert robust_calls == [("cam1", "pose/0007")]
    assert set(cal.views) == {(c, s) for c in ("cam0", "cam1") for s in poses} - {cut[0]}
    assert {(m.camera, m.step) for m in cal.missed} == {*cut, ("cam0", "pose/0007")}


@pytest.mark.slow
def test_a_grid_shifted_onto_the_boards_outer_edge_is_refused() -> None:
    """A board cut by the image's right edge (the realistic lab's camera 1 at pose 19): the
    classic detector finds a grid of the right size one column off, its left column on the
    pattern's outer edge against the white plate, 300 px from the true corners. The squares
    beyond that column are plate, not the print's outer ring, so the grid is refused (no
    board found) instead of entering the calibration with every corner wrong."""
    from calibration.camera.corners import UNSURE, _ring_is_printed, detect_corners_quickly

    rig, board = Rig(), Checkerboard(6, 9, 0.03)
    cam1 = pinhole("cam1", cam0_to_cam=RigidTransform(
        cv2.Rodrigues(np.array([0.0, np.pi / 6, 0.0]))[0], np.array([0.075, 0.0, -0.0201])))
    pose = RigidTransform(cv2.Rodrigues(np.array([2.5878, 0.2217, 0.4899]))[0],
                          np.array([-0.1573, 0.1241, 0.7830]))
    image = render_rig_image(cam1, rig, pose, np.random.default_rng(19))
    true = cam1.project(pose.apply(board.object_points()))
    assert detect_corners_quickly(image, board) is UNSURE
    assert detect_corners(image, board) is None
    # the same check keeps a board found whole: its true corners pass it
    whole = _pose((0.2, 0.1, 0.0), 0.7, rig)
    image = render_rig_image(CAMERA, rig, whole, np.random.default_rng(20))
    found = detect_corners(image, board)
    assert found is not None and _ring_is_printed(image, found, board)
    assert np.abs(found - CAMERA.project(whole.apply(board.object_points()))).max() < 0.1
    assert true[:, 0].max() > cam1.width  # the first board really runs off the image
    # nor does light falling off across the image (to a quarter from one side to the other)
    # make it refuse a whole board
    ramp = np.linspace(1.3, 0.3, image.shape[1])[None, :]
    dim = np.clip(image * ramp, 0, 255).astype(np.uint8)
    dimmed = detect_corners(dim, board)
    assert dimmed is not None and np.abs(dimmed - found).max() < 0.1
