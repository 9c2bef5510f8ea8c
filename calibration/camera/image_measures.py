"""Cheap measures of a checkerboard image that tell the capture's image mistakes apart: the
sharpness of the board's edges (motion blur), saturated pixels on the board (glare), the
quantised DCT of JPEG's 8 x 8 blocks (MJPEG), and the X-corners visible in an image where
the board was not found (a board half hidden).

Each measure is of the image alone, in pixels or grey levels; the thresholds that turn them
into findings, and why, are calibration.camera.image_checks'.
"""

from __future__ import annotations

import cv2
import numpy as np

from kernel.chessboard import as_grey

from .corners import Checkerboard

SATURATED = 254
"""Grey level (8-bit) from which a pixel counts as saturated."""

_PROFILE_SAMPLES = 25
"""Samples across an edge, from one square's middle to the other's (0.7 of a square)."""


def edge_sharpness(image: np.ndarray, corners_px: np.ndarray, board: Checkerboard) -> float:
    """The steepest slope across the board's edges over the step's height (1/px): the median
    over the edges between adjacent inner corners, of the edges along the rig's X and of those
    along Y, the smaller of the two. A step blurred by a Gaussian of sigma pixels has
    1 / (sigma sqrt(2 pi)) (0.4 at one pixel); blurred by a motion over L pixels about 1 / L
    across the edges the motion crosses: the smaller family sees a motion in any direction
    (by at least L / sqrt 2)."""
    grey = as_grey(image).astype(np.float32)
    grid = corners_px.reshape(board.corners_y, board.corners_x, 2)
    slopes = []
    for a, b in ((grid[:, :-1], grid[:, 1:]), (grid[:-1], grid[1:])):
        a, b = a.reshape(-1, 2), b.reshape(-1, 2)
        along = b - a
        length = np.linalg.norm(along, axis=1, keepdims=True)
        normal = np.stack([-along[:, 1], along[:, 0]], axis=1) / length
        t = np.linspace(-0.35, 0.35, _PROFILE_SAMPLES)[None, :, None] * length[:, :, None]
        points = ((a + b) / 2)[:, None, :] + t * normal[:, None, :]
        profile = cv2.remap(grey, points[..., 0].astype(np.float32),
                            points[..., 1].astype(np.float32), cv2.INTER_LINEAR)
        step = np.abs(profile[:, -3:].mean(axis=1) - profile[:, :3].mean(axis=1))
        slope = np.abs(np.diff(profile, axis=1)).max(axis=1) / (t[:, 1, 0] - t[:, 0, 0])
        slopes.append(float(np.median(slope / np.maximum(step, 1e-6))))
    return min(slopes)


SATURATED_MEDIAN_PX = 5
"""Side of the median filter applied before the saturated pixels are counted: a glare's disc
(tens of pixels across) survives it, single pixels that a noisy sensor's white squares push
to full scale do not (with 30 grey levels of noise about 13 % of a white square's pixels
reach 254: 3 % of the board, every view "in glare"; after the median, none)."""


def saturated_share(image: np.ndarray, hull_px: np.ndarray) -> float:
    """The share of the pixels inside the convex hull of `hull_px` (n, 2) at `SATURATED` or
    above after a median filter (`SATURATED_MEDIAN_PX`): 0 on a board lit without highlights
    (whose white squares are exposed below full scale), however noisy its sensor, the glare's
    disc on one that reflects a lamp."""
    grey = cv2.medianBlur(as_grey(image), SATURATED_MEDIAN_PX)
    mask = np.zeros(grey.shape, np.uint8)
    cv2.fillConvexPoly(mask, cv2.convexHull(np.round(hull_px).astype(np.int32)), 1)
    inside = grey[mask.astype(bool)]
    return float(np.mean(inside >= SATURATED)) if inside.size else 0.0


def saturated_reach(image: np.ndarray, spacing_px: float) -> float:
    """The area within one square (`spacing_px`, pixels) of a saturated pixel (counted as
    `saturated_share` counts them), in squares: about how many of a board's corners a
    highlight can hide from the detector. On the glared views of the 20-pose realistic
    sessions of five seeds, a highlight hid 6-14 corners with a reach of 14-30 squares."""
    grey = cv2.medianBlur(as_grey(image), SATURATED_MEDIAN_PX)
    side = 2 * round(spacing_px) + 1
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
    reach = cv2.dilate((grey >= SATURATED).astype(np.uint8), disc)
    return float(np.count_nonzero(reach)) / spacing_px ** 2


JPEG_COEFFICIENTS = ((0, 1), (1, 0), (1, 1), (0, 2), (2, 0), (1, 2), (2, 1), (2, 2))
"""The 8 x 8 DCT coefficients (row, column) whose quantisation `jpeg_quantisation` looks for:
the lowest AC ones, whose steps at the qualities webcams use lie between 2 (quality 90) and
16 (quality 50)."""

JPEG_STEPS = range(2, 17)
"""Quantisation steps tried. A step of 1 (quality 98 and above) leaves nothing to see, nor
does it move a corner; steps above 16 matched the board's own edges on low-noise frames."""

JPEG_MIN_VALUES = 500
"""Fewest coefficients beyond half a step from 0 for a step to be judged."""


def jpeg_quantisation(image: np.ndarray) -> float:
    """How closely the low DCT coefficients of the image's 8 x 8 blocks sit on multiples of
    one step: near 1 for a frame decoded from JPEG, near 0 for a raw one.

    JPEG stores each block's DCT (the orthonormal 2-D DCT-II of the grey levels less 128)
    divided by a step per coefficient and rounded; the decoded frame gives back those
    multiples, blurred only by its rounding to integers (0.29 of a level). For each of
    `JPEG_COEFFICIENTS` and `JPEG_STEPS`, the mean of cos(2 pi c / step) over the blocks'
    coefficients c further than half a step from 0 (the zeros of flat areas would match
    any step); the largest. A sensor's noise, which hid JPEG's block seams at gain 16, is
    quantised with the rest and hides nothing here."""
    grey = as_grey(image).astype(np.float32) - 128.0
    height, width = (grey.shape[0] // 8) * 8, (grey.shape[1] // 8) * 8
    blocks = (grey[:height, :width].reshape(height // 8, 8, width // 8, 8)
              .swapaxes(1, 2).reshape(-1, 8, 8))
    basis = _dct_basis()
    coefficients = basis @ blocks @ basis.T
    best = 0.0
    for row, column in JPEG_COEFFICIENTS:
        values = coefficients[:, row, column]
        for step in JPEG_STEPS:
            beyond = values[np.abs(values) > step / 2]
            if beyond.size < JPEG_MIN_VALUES:
                break
            best = max(best, float(np.mean(np.cos(2 * np.pi * beyond / step))))
    return best


def _dct_basis() -> np.ndarray:
    """(8, 8) the orthonormal DCT-II matrix: row k is cos((2 n + 1) k pi / 16), scaled."""
    n = np.arange(8)
    basis = np.cos((2 * n[None, :] + 1) * n[:, None] * np.pi / 16) * np.sqrt(2 / 8)
    basis[0] /= np.sqrt(2)
    return basis.astype(np.float32)


def x_corner_response(image: np.ndarray) -> np.ndarray:
    """The checkerboard X-corner response at every pixel (grey levels^2 / px^4): minus the
    determinant of the Hessian of the image smoothed over 1.5 px, large where two dark and
    two light quadrants meet, small on edges, flat areas and noise."""
    grey = cv2.GaussianBlur(as_grey(image).astype(np.float32), (0, 0), 1.5)
    xx = cv2.Sobel(grey, cv2.CV_32F, 2, 0, ksize=3)
    yy = cv2.Sobel(grey, cv2.CV_32F, 0, 2, ksize=3)
    xy = cv2.Sobel(grey, cv2.CV_32F, 1, 1, ksize=3)
    return np.asarray(xy * xy - xx * yy)


def x_corners(image: np.ndarray, level: float, square_px: float) -> np.ndarray:
    """(n, 2) pixels of the checkerboard X-corners in an image of squares `square_px` wide:
    the local maxima of `x_corner_response` above `level`, at least half a square apart, whose
    surroundings alternate dark, light, dark, light (`x_shape`).

    The response alone also peaks where a square's corner meets the board's white margin (an
    L-corner) or where an arm's edge crosses a square's (a T-junction): on a realistic image
    of a board 40 % hidden it found 49 peaks where 32 corners were in view."""
    response = x_corner_response(image)
    size = 2 * max(1, int(square_px / 2) // 2) + 1
    peaks = (response >= cv2.dilate(response, np.ones((size, size), np.uint8))) & (
        response > level)
    v, u = np.nonzero(peaks)
    found = np.stack([u, v], axis=1).astype(np.float64)
    return found[x_shape(image, found, X_SHAPE_RADIUS * square_px) >= X_SHAPE_RATIO]


X_SHAPE_RADIUS = 0.35
"""The circle `x_shape` samples, in squares: inside the four squares that meet at a corner
(half a square along the grid's lines, less where the view foreshortens them)."""

X_SHAPE_RATIO = 1.2
"""Least `x_shape` of an X-corner. On 150 images of five realistic 30-pose sessions (noise,
vignetting, the lamp, gamma, the bow) the 8100 board corners lay at 7.6-150 and the 739
other peaks (L-corners at the margin) at 0.82 at most; on a board 40 % hidden, the corners the
arm's edge cuts into lay at 1.4-2.3 (one quadrant partly covered: still in view), the
T-junctions of its edge with the squares' at 0.85 at most."""

_X_SHAPE_SAMPLES = 16
"""Points on the circle (the fourth harmonic, the highest that matters, has four each)."""


def x_shape(image: np.ndarray, points_px: np.ndarray, radius_px: float) -> np.ndarray:
    """(n,) how much each point looks like an X-corner: the grey levels on a circle of
    `radius_px` about it, their second harmonic's amplitude over their first's.

    Four quadrants alternating dark and light go round the circle twice (second harmonic);
    one dark quadrant in the light (an L-corner) or an edge ending on another (a T-junction)
    goes round once (first harmonic), a straight edge likewise."""
    if len(points_px) == 0:
        return np.zeros(0)
    grey = cv2.GaussianBlur(as_grey(image).astype(np.float32), (0, 0), 1.0)
    angles = 2 * np.pi * np.arange(_X_SHAPE_SAMPLES) / _X_SHAPE_SAMPLES
    xs = (points_px[:, :1] + radius_px * np.cos(angles)).astype(np.float32)
    ys = (points_px[:, 1:] + radius_px * np.sin(angles)).astype(np.float32)
    ring = cv2.remap(grey, xs, ys, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    harmonics = np.abs(np.fft.rfft(ring, axis=1))
    return np.asarray(harmonics[:, 2] / np.maximum(harmonics[:, 1], 1e-9))
