"""How far the printed board bows out of its plane, estimated from the corners of every view.

Why: the camera model takes the board as flat. A print on a plate that is not (a warped
plate, a print lifting off it) puts its inner corners off the plane by up to the bow; seen
from 0.6-1 m that moves corners by tenths of a pixel, which the fit spreads over the
intrinsics, the distortion and the board poses, and so into the speakers' positions.

Model: one parameter, a paraboloid sag of the pattern, z = s (1 - r^2 / R^2) in the rig
frame, r the distance from the centre of the inner-corner grid and R that of its corners:
the grid's outer corners stay in the plane z = 0, its centre is s out of it (s > 0: towards
+Z, out of the printed face). It is estimated by calibrating each camera again (its
intrinsics, distortion and every board pose free) with the corners' rig coordinates sagged
by s, for a few s: the sum over the cameras of the squared residuals over each camera's
corner noise (calibration.camera.corner_noise) is a chi-square, quadratic in s near its minimum,
whose curvature gives the estimate's standard deviation. The noise given is the flat board's
fit's, which a bow inflates (its misfit taken for noise: 2-3 times the true noise for 0.5 mm
seen from 0.6-1 m); so the curvature is scaled by the chi-square per degree of freedom at the
minimum, which puts the bowed board's noise in its place (the cameras' given noises only weigh
them against each other).

A significant sag (`BOW_SIGNIFICANT`) is modelled: the cameras are calibrated again with the
sagged corners (calibration.camera.camera_calibration), and the joint fit uses the same points
(`board_points`), so that every board pose, the intrinsics and the corner noise come from one
board; a smaller one is a bound, the board taken as flat.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .corners import Checkerboard

PROBE_SAG_M = (-1e-3, 0.0, 1e-3)
"""Sags (metres, about the estimate) the chi-square is evaluated at, first about the flat
board, then about that first estimate: the bows a print on a plate shows (a millimetre or
two over 25 cm). Recovered within its std (8 um from 15 views at 0.05 px) for sags of 0
to 3 mm; a few tenths of a second per camera at 15-30 views."""
_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-12)
_MIN_SIGMA_PX = 1e-6
"""Least corner noise a camera's residuals are divided by (exact synthetic corners have 0)."""
BOW_SIGNIFICANT = 3.0
"""A sag this many of its standard deviations from 0 is modelled (`BoardBow.significant`); a
smaller one is a bound (the report states it), and the board is taken as flat rather than with
a sag that is mostly its estimate's noise."""


@dataclass(frozen=True)
class BoardBow:
    """The board's sag (see the module docstring).

    Attributes:
        sag_m: the grid centre's distance out of the plane of its corners, metres (+: +Z).
        std_m: its standard deviation, metres.
        n_views: board views it was estimated from.
    """

    sag_m: float
    std_m: float
    n_views: int

    @property
    def significant(self) -> bool:
        """Whether the sag is modelled: `BOW_SIGNIFICANT` of its std from 0."""
        return abs(self.sag_m) > BOW_SIGNIFICANT * self.std_m


def sagged_points(board: Checkerboard, sag_m: float) -> np.ndarray:
    """(n_corners, 3) the board's inner corners in the rig frame with a sag of `sag_m`."""
    points = board.object_points()
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    r2 = np.sum(xy**2, axis=1)
    points[:, 2] = sag_m * (1.0 - r2 / r2.max())
    return points


def board_points(board: Checkerboard, bow: BoardBow | None) -> np.ndarray:
    """(n_corners, 3) the board's inner corners in the rig frame as the calibration models
    them: sagged by `bow` where it is significant, flat otherwise (or without an estimate)."""
    if bow is not None and bow.significant:
        return sagged_points(board, bow.sag_m)
    return board.object_points()


@dataclass(frozen=True)
class CameraViews:
    """What the bow is estimated from for one camera.

    Attributes:
        K: (3, 3) intrinsic matrix (the start of its calibrations), pixels.
        dist: (5,) distortion (OpenCV's order).
        size: the image's (width, height), pixels.
        corners_px: the corners (n_corners, 2) of each of its views, rig order.
        sigma_px: its corner noise per coordinate, pixels (calibration.camera.corner_noise).
    """

    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int]
    corners_px: list[np.ndarray]
    sigma_px: float


def estimate_bow(board: Checkerboard, cameras: list[CameraViews]) -> BoardBow:
    """The board's sag from every camera's views (at least 4 each: calibrateCamera's)."""

    def chi2(sag: float) -> float:
        obj = sagged_points(board, sag).astype(np.float32)
        total = 0.0
        for cam in cameras:
            image_points = [c.astype(np.float32).reshape(-1, 1, 2) for c in cam.corners_px]
            rms = cv2.calibrateCamera([obj] * len(image_points), image_points, cam.size,
                                      cam.K.copy(), cam.dist.copy(),
                                      flags=cv2.CALIB_USE_INTRINSIC_GUESS, criteria=_CRITERIA)[0]
            total += (rms**2 * sum(len(c) for c in cam.corners_px)
                      / max(cam.sigma_px, _MIN_SIGMA_PX) ** 2)
        return total

    centre = 0.0
    for _ in range(2):  # about the flat board, then about the first estimate
        sags = centre + np.array(PROBE_SAG_M)
        quadratic = np.polyfit(sags, [chi2(s) for s in sags], 2)
        a, b = quadratic[:2]
        centre = -b / (2 * a) if a > 0 else centre
    n_views = sum(len(cam.corners_px) for cam in cameras)
    if a <= 0:
        return BoardBow(float(centre), float("inf"), n_views)
    # coordinates less each view's pose, each camera's 9 intrinsics and the sag
    dof = sum(2 * sum(len(c) for c in cam.corners_px) - 6 * len(cam.corners_px) - 9
              for cam in cameras) - 1
    reduced = max(float(np.polyval(quadratic, centre)), 0.0) / dof
    return BoardBow(float(centre), float(np.sqrt(reduced / a)), n_views)
