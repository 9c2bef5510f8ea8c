"""The quick look for a chessboard that the daemon's checks and the calibration share.

One detector, so that a pose the daemon accepted as "checkerboard found" is one the
calibration's quick path finds too (and the daemon's preview shows the corners the
calibration starts from): OpenCV's fast check (cv2.checkChessboard) on the image shrunk by
`scale`, again at full size where that misses (the shrunk check misses 2-4 % of the boards
the detector then finds; at full size it costs about 9 ms on a 1280 x 960 image), then the
classic detector on the shrunk image (`classic_grid`, which the calibration's full-size look
uses too; a board it misses is the sector-based detector's, which the calibration runs where
the quick look was unsure).

The corners are not refined: they are where the detector put them, in full-image pixels.
The calibration refines them on the full image; the daemon only draws and checks them.

cv2 is imported when a look is taken, not with this module: the kernel loads nothing heavy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class QuickLook:
    """What a quick look saw.

    Attributes:
        board_seen: the fast check saw a chessboard of the pattern.
        corners_px: (n, 2) the pattern's inner corners in OpenCV's order (row after row of
            `pattern_size[0]`), full-image pixels, unrefined; None where the classic detector
            did not find the whole grid (the board may be cut by the image's edge, or lit
            unevenly).
    """

    board_seen: bool
    corners_px: np.ndarray | None


def as_grey(image: np.ndarray) -> np.ndarray:
    """`image` as one grey channel (a grey image as it is, a BGR one converted)."""
    if image.ndim == 2:
        return image
    import cv2

    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def quick_look(image: np.ndarray, pattern_size: tuple[int, int], scale: float) -> QuickLook:
    """Look for a chessboard of `pattern_size` inner corners (x by y) in `image`, on the image
    shrunk by `scale` (0 < scale <= 1; INTER_AREA, whose pixel centres map back to the full
    image as (shrunk + 1/2) / scale - 1/2)."""
    import cv2

    if not 0 < scale <= 1:
        raise ValueError(f"a quick look shrinks the image by a scale in (0, 1], not {scale}")
    full = as_grey(image)
    shrunk = (full if scale == 1 else
              cv2.resize(full, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA))
    if not (cv2.checkChessboard(shrunk, pattern_size)
            or (scale < 1 and cv2.checkChessboard(full, pattern_size))):
        return QuickLook(board_seen=False, corners_px=None)
    corners = classic_grid(shrunk, pattern_size)
    if corners is None:
        return QuickLook(board_seen=True, corners_px=None)
    return QuickLook(board_seen=True, corners_px=(corners + 0.5) / scale - 0.5)


def classic_grid(grey_image: np.ndarray, pattern_size: tuple[int, int]) -> np.ndarray | None:
    """The classic detector's (cv2.findChessboardCorners) inner corners of the whole grid,
    (n, 2) pixels in OpenCV's order, unrefined, or None.

    Without adaptive thresholding: on the realistic lab's images (30 poses, 3 cameras) it
    finds the same boards in a fraction of the time, and where it fails (a board cut by the
    image's edge) it fails in a fraction of it too; the sector-based detector is the one
    robust to uneven light, and it found every board the adaptive classic one found."""
    import cv2

    flags = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(grey_image, pattern_size, flags=flags)
    return corners.reshape(-1, 2).astype(np.float64) if found else None
