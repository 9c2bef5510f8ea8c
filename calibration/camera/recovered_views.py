"""Board views recovered in part: the corners of an image where no detector found the board
(a highlight over part of it, an arm in front of it), refitted where the rig's pose puts them.

A pose whose every view was left out is still placed by its own times of flight
(calibration.pipeline `_placed_by_their_bursts`), to about a pixel in the image. That places
every inner corner of the board too, and the blurred-corner fit (calibration.camera.corners)
refines each from there as it refines a detector's corners: the prediction only says which
corner is which and where to start, the pixels say where it is. A corner is kept when its
fit succeeds (it rejects a fit much worse than the board's others: glare or an arm across
the corner), lands within `MAX_START_ERROR_PX` of the prediction, lies at least
`GLARE_CLEARANCE_SQUARES` from any saturated pixel, and agrees with the pose the kept corners
fit (`TRIM_SIGMAS`). The joint fit then uses the view's kept corners with the others' rows
left empty; what was left of a view is in the calibration's notes.

Started 1-2.5 px off, the corners of the realistic lab's found boards come back within 2e-6 px
of the detector's. On its 20-pose sessions the glared views of seeds 1 and 5 keep 29 and 24 of
the 54 corners, as true as a found view's (seed 5: 0.035 px RMS per coordinate from the
truth, the other views 0.025-0.043), and the half-hidden board of seed 5 keeps 23.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from acquisition.contracts.session import SessionReader
from kernel.chessboard import as_grey
from kernel.rigid import RigidTransform

from .camera_calibration import BoardView, CameraCalibration, CameraIntrinsics, partial_view
from .corners import Checkerboard, fit_corners_from
from ..result import Finding

MAX_START_ERROR_PX = 3.0
"""A refitted corner further than this from where the rig's placed pose predicts it is not
believed, pixels: the times of flight place the rig to about a pixel in the image (0.6-1.0 px
on the realistic lab's glared views), and a corner's neighbours lie 25 px or more away."""
SATURATED_GREY = 250
"""A pixel at or above this grey level is saturated (or nearly: a highlight's rim)."""
GLARE_CLEARANCE_SQUARES = 1.5
"""Nearest a kept corner may lie to a saturated pixel, in the board's squares (as imaged).
A highlight's light falls off over a square or more beyond what it saturates, and its slope
moves a corner fit that models a constant brightness. Against the truth, on the realistic
lab's glared views of seeds 1, 3 and 5 (20 poses; corner noise 0.032-0.034 px per
coordinate on their other views): corners within half a square of a saturated pixel were off
by 0.17-0.34 px RMS, from half a square to one by 0.06-0.16, from one to 1.5 by 0.035-0.053,
from 1.5 on by 0.025-0.045 (the noise)."""
TRIM_SIGMAS = 3.5
"""A kept corner whose distance from its fitted pose exceeds this many times the camera's
corner noise (per coordinate) is dropped, the worst first, and the pose fitted again: for
Gaussian noise a 2-D residual that large has a chance of 0.2 %."""
MIN_RECOVERED_SHARE = 0.25
"""Fewest kept corners, as a share of the board's, for the view to be used: fewer span too
little of the board to fit its pose well, and say that most of it was spoiled."""
MIN_RECOVERED_CORNERS = 8
"""And never fewer than this (the pose has 6 unknowns; a few more let `TRIM_SIGMAS` judge)."""


@dataclass(frozen=True)
class RecoveredView:
    """A view recovered in part.

    Attributes:
        view: the board view, its `corners_px` NaN where a corner was not kept.
        kept: how many corners were kept.
        near_glare: how many corners were dropped for lying near saturated pixels.
    """

    view: BoardView
    kept: int
    near_glare: int


def recover_view(grey: np.ndarray, board: Checkerboard, points: np.ndarray,
                 intr: CameraIntrinsics, step: str, rig_to_cam: RigidTransform
                 ) -> RecoveredView | None:
    """The view of `intr`'s camera at `step` from its 8-bit grey image, with the board's
    corners (`points`, rig frame, metres) predicted by the rig's pose in that camera's frame
    `rig_to_cam`; None when too few corners are kept (`MIN_RECOVERED_SHARE`,
    `MIN_RECOVERED_CORNERS`) or the board lies behind the camera."""
    in_cam = rig_to_cam.apply(points)
    if np.any(in_cam[:, 2] <= 0):
        return None
    predicted, _ = cv2.projectPoints(in_cam, np.zeros(3), np.zeros(3), intr.K, intr.dist)
    predicted = predicted.reshape(-1, 2)
    fitted, ok = fit_corners_from(grey, predicted, board)
    keep = ok & (np.linalg.norm(fitted - predicted, axis=1) <= MAX_START_ERROR_PX)
    clear = _glare_clearance_squares(grey, fitted, predicted, board) >= GLARE_CLEARANCE_SQUARES
    near_glare = int(np.sum(keep & ~clear))
    keep &= clear
    needed = max(MIN_RECOVERED_CORNERS, int(np.ceil(MIN_RECOVERED_SHARE * board.n_corners)))
    while keep.sum() >= needed:
        corners = np.where(keep[:, None], fitted, np.nan)
        view = partial_view(intr.name, step, corners, intr, points, rig_to_cam)
        if view is None:
            return None
        miss = _misfit_px(view, intr, points)
        worst = int(np.nanargmax(miss))
        if miss[worst] <= TRIM_SIGMAS * intr.noise.sigma_px:
            return RecoveredView(view, int(keep.sum()), near_glare)
        keep[worst] = False
    return None


def _glare_clearance_squares(grey: np.ndarray, fitted: np.ndarray, predicted: np.ndarray,
                             board: Checkerboard) -> np.ndarray:
    """(n,) each corner's distance from the nearest saturated pixel, in the board's squares
    as imaged (the median spacing of the predicted grid); infinite without any."""
    saturated = grey >= SATURATED_GREY
    if not saturated.any():
        return np.full(len(fitted), np.inf)
    distance = cv2.distanceTransform((~saturated).astype(np.uint8), cv2.DIST_L2, 5)
    grid = predicted.reshape(board.corners_y, board.corners_x, 2)
    spacing = float(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=-1)))
    height, width = grey.shape
    at = np.clip(np.rint(fitted), 0, [width - 1, height - 1]).astype(int)
    return distance[at[:, 1], at[:, 0]] / spacing


def _misfit_px(view: BoardView, intr: CameraIntrinsics, points: np.ndarray) -> np.ndarray:
    """(n,) each corner's distance from where the view's pose puts it, pixels (NaN where the
    view lacks it)."""
    pose = view.rig_to_cam.transform
    projected, _ = cv2.projectPoints(points, pose.rotvec, pose.t, intr.K, intr.dist)
    return np.linalg.norm(view.corners_px - projected.reshape(-1, 2), axis=1)


def recover_views(cams: CameraCalibration, reader: SessionReader,
                  placed: dict[str, RigidTransform]
                  ) -> tuple[CameraCalibration, dict[tuple[str, str], RecoveredView]]:
    """`cams` with the views recovered in part (`recover_view`) at the steps no camera
    located, given their rig poses in the camera-0 frame (`placed`, by step), and those views
    by (camera, step). An image blurred by motion is not tried (every corner of it is
    smeared), nor one a camera has no image of.

    Only there: recovering the views that the other cameras' poses predict (the boards that
    run off a camera's image where camera 0 located them) was tried on the realistic lab's
    30-pose sessions with three cameras, and moved the mean error of seeds 1-5 from
    0.022 / 0.021 / 0.034 / 0.022 / 0.041 mm to 0.020 / 0.021 / 0.036 / 0.024 / 0.039: no gain
    for the time."""
    blurred = {(camera, step) for f in cams.findings if f.kind == "motion-blur"
               for camera in f.cameras for step in f.poses}
    steps = reader.steps()
    views = dict(cams.views)
    recovered: dict[tuple[str, str], RecoveredView] = {}
    for step, rig_to_cam0 in sorted(placed.items()):
        for camera, intr in cams.intrinsics.items():
            key = (camera, step)
            if key in views or key in blurred or f"{camera}.png" not in steps[step].files:
                continue
            rig_to_cam = cams.cam_from_cam0[camera].cam0_to_cam.compose(rig_to_cam0)
            grey = as_grey(reader.read_image(step, f"{camera}.png"))
            found = recover_view(grey, cams.board, cams.board_points(), intr, step, rig_to_cam)
            if found is not None:
                views[key], recovered[key] = found.view, found
    return replace(cams, views=views), recovered


def recovery_note(key: tuple[str, str], found: RecoveredView, n_corners: int) -> str:
    """What the calibration's notes say of a view recovered in part."""
    glare = f", {found.near_glare} left out near saturated pixels" if found.near_glare else ""
    return (f"{key[0]} {key[1]}: {found.kept} of the board's {n_corners} corners were found "
            f"again where the rig's times of flight put them{glare}, and used in the joint fit")


def with_recovery(finding: Finding, recovered: dict[tuple[str, str], RecoveredView]
                  ) -> Finding:
    """A finding that left views out (`finding.action` "left out"), its evidence telling how
    much of each was recovered; any other finding as it is."""
    keys = [(c, s) for c in finding.cameras for s in finding.poses if (c, s) in recovered]
    if finding.action != "left out" or not keys:
        return finding
    parts = "; ".join(f"{recovered[k].kept} of the corners at {k[1]} in {k[0]}" for k in keys)
    return finding.model_copy(update={
        "evidence": f"{finding.evidence} ({parts} were found again where the rig's times of "
                    "flight put them, and used)"})
