"""The rig's checkerboard and its corners in an image, in the rig frame's order.

Frames (see DESIGN.md, "Calibration"):
- the *rig frame* is the paper's: origin at an extreme inner corner, X along the side with
  `corners_x` (6) corners, Y along the side with `corners_y` (9), Z out of the printed face;
- OpenCV returns the corners in an order of its own: rows of `corners_x` corners, starting at
  whichever end it found first. Four orders keep that row structure (the identity, a flip of
  X, of Y, or both). A flip of one axis is a mirror: it would put Z behind the printed face,
  which `_to_rig_order` rejects by the handedness of the grid in the image (the camera sees the
  printed face, so rig Z points towards it). The remaining two differ by a half-turn, the
  checkerboard's 180-degree ambiguity; the paper's speaker layout is symmetric under it (a
  wrong choice swaps speakers 1<->4, 2<->3, 5<->6), so it is resolved from the square colours:
  the square on the +X +Y side of the rig origin is printed in the colour the rig description
  states (`origin_square`: dark in micam's own print, sim.light), the one at the opposite end
  in the other colour when corners_x + corners_y is odd (a 6 x 9 grid); a pattern that looks
  the same after a half-turn needs a marker (a dot of the other colour in one square off the
  centre, `marker_square`), which the rig description insists on.
- a board pose (rvec, tvec) maps rig coordinates into the camera's: x_cam = R(rvec) x_rig + t.

Detection is fast where it can be: on a full-size image without a board, OpenCV's classic
detector takes seconds (adaptive thresholding of sensor noise yields many candidate quads),
so the fast check runs first on its own (about 10 ms), then the classic detector on a
half-size image (1-2 ms when the board is there; at quarter size it misses some), and the
robust sector-based detector (findChessboardCornersSB, 0.1-0.4 s) at full size only when
that fails (a caller that can tell a board cut by the image's edge, as the camera calibration
can from the other cameras' views, skips it there). The corners are then
refined with cornerSubPix on the full-resolution image (about 0.05 px RMS on the
simulated images, against 0.07 px with occasional 0.5 px outliers from findChessboardCornersSB
alone).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from acquisition.contracts.rig_description import RigDescription

_CLASSIC_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
"""The classic detector without adaptive thresholding: on the realistic lab's images (30
poses, 3 cameras) it finds the same 49 boards in 3.7 ms per image instead of 35 ms, and where
it fails (a board cut by the image's edge) it fails in 4 ms instead of 120-360 ms; the
sector-based fallback is the detector robust to uneven light, and it found every board the
adaptive classic one found."""
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
_SUBPIX_WINDOW_FRACTION = 0.3
"""cornerSubPix half-window as a fraction of the smallest corner spacing: the window must
stay inside the four squares around a corner, and be as large as that allows to average the
most edge pixels."""
_SUBPIX_HALF_WINDOW_PX = (2, 10)


@dataclass(frozen=True)
class Checkerboard:
    """The printed checkerboard of the rig (see the module docstring for its frame).

    Attributes:
        corners_x: inner corners along the rig's X axis (6).
        corners_y: inner corners along the rig's Y axis (9).
        square_m: side of a square, metres.
        origin_dark: the square between the origin corner and its +X, +Y neighbours is dark.
        marker_square: (i, j) of a square with a dot of the other colour at its centre, or
            None.
    """

    corners_x: int
    corners_y: int
    square_m: float
    origin_dark: bool = True
    marker_square: tuple[int, int] | None = None

    @classmethod
    def of_rig(cls, rig: RigDescription) -> Checkerboard:
        """The board of a rig description (`SessionData.rig`)."""
        marker = None if rig.marker_square is None else tuple(rig.marker_square)
        return cls(rig.corners_x, rig.corners_y, rig.square_m, rig.origin_square == "dark",
                   marker)  # type: ignore[arg-type]

    @property
    def pattern_size(self) -> tuple[int, int]:
        """OpenCV's pattern size: corners per row (along X), rows (along Y)."""
        return self.corners_x, self.corners_y

    @property
    def n_corners(self) -> int:
        return self.corners_x * self.corners_y

    def object_points(self) -> np.ndarray:
        """(n_corners, 3) inner corners in the rig frame, metres, X varying fastest."""
        ix, iy = np.meshgrid(np.arange(self.corners_x), np.arange(self.corners_y))
        xy = np.stack([ix.ravel(), iy.ravel()], axis=1) * self.square_m
        return np.hstack([xy, np.zeros((xy.shape[0], 1))])


def detect_corners(image: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """The board's inner corners in rig order (X fastest), (n_corners, 2) pixels, or None:
    `detect_corners_quickly`, then `detect_corners_robustly` where it was unsure.

    Args:
        image: uint8 grey (h, w) or BGR (h, w, 3) image.
        board: the checkerboard to look for.
    """
    quick = detect_corners_quickly(image, board)
    return detect_corners_robustly(image, board) if isinstance(quick, Unsure) else quick


class Unsure:
    """The type of `UNSURE`."""

    def __repr__(self) -> str:
        return "UNSURE"


UNSURE = Unsure()
"""What `detect_corners_quickly` returns when the fast check sees a board that the classic
detector cannot find whole: a board cut by the image's edge, or one that only the robust
detector finds (small, distant, unevenly lit)."""


def detect_corners_quickly(image: np.ndarray, board: Checkerboard,
                           full_size_check: bool = True) -> np.ndarray | None | Unsure:
    """The corners (as `detect_corners`) from the cheap detectors alone, None when the fast
    check sees no board, or `UNSURE`.

    cv2.checkChessboard (the detector's own fast check) rejects most images without a board:
    at half size first (about 1 ms), at full size (about 9 ms) only when that fails (it misses
    2-4 % of the boards the detector then finds) and `full_size_check` asks for it; then the
    classic detector at half size (`_CLASSIC_FLAGS`)."""
    grey = _grey(image)
    half = cv2.resize(grey, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    if not (cv2.checkChessboard(half, board.pattern_size)
            or (full_size_check and cv2.checkChessboard(grey, board.pattern_size))):
        return None
    found, corners = cv2.findChessboardCorners(half, board.pattern_size, flags=_CLASSIC_FLAGS)
    if not found:
        return UNSURE
    # pixel centres: full = (half + 1/2) * 2 - 1/2 (INTER_AREA averages 2 x 2 blocks)
    return _finished(grey, (corners.reshape(-1, 2) + 0.5) * 2.0 - 0.5, board)


def detect_corners_robustly(image: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """The corners (as `detect_corners`) from the sector-based detector at full size
    (findChessboardCornersSB, 0.1-0.4 s, and as long to fail on a board cut by the image's
    edge), or None."""
    grey = _grey(image)
    found, corners = cv2.findChessboardCornersSB(grey, board.pattern_size)
    return _finished(grey, corners.reshape(-1, 2), board) if found else None


def _grey(image: np.ndarray) -> np.ndarray:
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def _finished(grey: np.ndarray, corners: np.ndarray, board: Checkerboard) -> np.ndarray:
    """Approximate corners (n, 2) in OpenCV's order, refined and put in rig order."""
    return _to_rig_order(grey, _refine(grey, corners.astype(np.float64), board), board)


def _refine(grey: np.ndarray, corners: np.ndarray, board: Checkerboard) -> np.ndarray:
    """Corners refined by cornerSubPix with a window sized to the smallest corner spacing."""
    grid = corners.reshape(board.corners_y, board.corners_x, 2)
    spacing = min(
        np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
        np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
    )
    half = int(np.clip(round(_SUBPIX_WINDOW_FRACTION * spacing), *_SUBPIX_HALF_WINDOW_PX))
    refined = cv2.cornerSubPix(
        grey,
        corners.astype(np.float32).reshape(-1, 1, 2),
        (half, half),
        (-1, -1),
        _SUBPIX_CRITERIA,
    )
    return refined.reshape(-1, 2).astype(np.float64)


def _to_rig_order(grey: np.ndarray, corners: np.ndarray, board: Checkerboard) -> np.ndarray:
    """Reorder OpenCV's corners (rows of corners_x) into the rig frame's order.

    Of the four orders that keep the rows (identity, X flip, Y flip, both), the two that are
    right-handed with Z towards the camera differ by a half-turn; the one kept has its colours
    (and marker) where the print has them.
    """
    grid = corners.reshape(board.corners_y, board.corners_x, 2)
    handed = [c for c in (grid, grid[:, ::-1], grid[::-1, :], grid[::-1, ::-1])
              if _faces_camera(c)]
    best = max(handed, key=lambda c: _colour_score(grey, c, board))
    return best.reshape(-1, 2)


def _faces_camera(grid: np.ndarray) -> bool:
    """True if the grid's X and Y axes, seen in the image, make Z point at the camera.

    With Z towards the camera (against the optical axis) X and Y turn clockwise in the
    image's (u right, v down) coordinates: X to the right puts Y upwards. The sign of the 2D
    cross product of the grid's mean X and Y steps tells.
    """
    step_x = (grid[:, -1] - grid[:, 0]).sum(axis=0)
    step_y = (grid[-1, :] - grid[0, :]).sum(axis=0)
    return float(step_x[0] * step_y[1] - step_x[1] * step_y[0]) < 0.0


def _colour_score(grey: np.ndarray, grid: np.ndarray, board: Checkerboard) -> float:
    """How well the squares between the corners have the colours the print gives them
    (positive: they do).

    Square (i, j) between corners (i, j) and (i + 1, j + 1) is dark when i + j is even and the
    origin square is dark (sim.light), when i + j is odd otherwise; the marker square, if any,
    shows the other colour at its centre. The grey level at every square centre is correlated
    with that pattern, so one misread square cannot flip the decision.
    """
    centres = (grid[:-1, :-1] + grid[1:, :-1] + grid[:-1, 1:] + grid[1:, 1:]) / 4
    h, w = grey.shape
    u = np.clip(np.rint(centres[..., 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(centres[..., 1]).astype(int), 0, h - 1)
    level = grey[v, u].astype(np.float64)
    j, i = np.indices(level.shape)
    dark_sign = np.where((i + j) % 2 == (0 if board.origin_dark else 1), -1.0, 1.0)
    if board.marker_square is not None:
        mi, mj = board.marker_square
        dark_sign[mj, mi] *= -1.0
    return float(np.sum(dark_sign * (level - level.mean())))
