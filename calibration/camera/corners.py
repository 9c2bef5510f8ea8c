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
refined on the full-resolution image: by cornerSubPix first (findChessboardCornersSB's own
corners are off by 0.07 px RMS, with occasional 0.5 px outliers), then by a fit of the blurred
corner's model to the pixels around each (`_fit_corners`). cornerSubPix alone is biased by
the way it interpolates the image's gradients ("pixel locking"): on the simulated images
0.016-0.048 px RMS per coordinate without any noise, depending on the pose (the same on float
or 4x-supersampled renders), a board's mean off by up to 0.05 px, and 0.026 px RMS on a
30-view session with 2 grey levels of noise. The fit models the pixels as sim.light forms
them (and nearly as a camera does) and has no such bias: 0.0007-0.0022 px RMS on noise-free
renders (the 8-bit rounding; 0.0001 px on float ones), 0.006 px with 2 grey levels of noise
(the noise itself); where it fails (see `_fit_corners`) it is fitted again from where its
fitted neighbours put it (`_refine`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from acquisition.contracts.rig_description import RigDescription
from kernel.chessboard import as_grey, classic_grid, quick_look

_DETECT_SMOOTH_PX = 1.0
"""Gaussian sigma (pixels) of the smoothing the full-size classic detector looks at (the
corners are refined on the image itself): on a noisy sensor's images (30 grey levels) the
noise makes it 2-3 s per image, smoothed 0.04-0.07 s, finding the same boards."""
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
_SUBPIX_WINDOW_FRACTION = 0.3
"""cornerSubPix half-window as a fraction of the smallest corner spacing: the window must
stay inside the four squares around a corner, and be as large as that allows to average the
most edge pixels."""
_SUBPIX_HALF_WINDOW_PX = (2, 10)
_FIT_HALF_WINDOW_PX = (3.0, 8.0)
"""Smallest and largest radius of the disc the corner model is fitted on, pixels: below 3 px
too few edge pixels are left; 8 px weighs the fit's time against its noise (a larger disc
costs time for a little less noise, a smaller one saves time for more)."""
_FIT_MARGIN_PX = 2.5
"""Clearance between the fit's disc and the sides of the four squares around a corner,
pixels: the blur (about 2 sigma) and the pixel (half a pixel) spread an edge that far."""
_BLUR_TAPS = 3
"""Taps either side of the model's Gaussian blur: OpenCV's GaussianBlur uses 3 for sigma
0.6 px on a float image (sim.light), and 3 taps reach 5 sigma of that blur."""
_BLUR_START_PX = 0.7
"""Blur sigma the fit starts from, pixels (a sharp lens is at 0.5-1 px)."""
_BLUR_RANGE_PX = (0.05, 3.0)
"""Range the fitted blur sigma is kept in, pixels (below 0.05 px the taps are a single one)."""
_FIT_ITERATIONS = 8
"""Most Gauss-Newton steps: from cornerSubPix's corners the largest step of a board is about
0.05 px, then 0.01 px, then below 1e-3 px; most corners converge in three."""
_FIT_DAMPED_AFTER = 3
"""Steps after this many are halved: the model is only piecewise smooth (an edge crossing a
pixel's centre changes which pixels see its ramp), so a corner can swing between two
positions about 1e-3 px apart; halved steps settle between them."""
_FIT_TOLERANCE_PX = 1e-3
"""A corner whose step (after the first: the residuals' RMS, which `_FIT_RESIDUAL_RATIO`
checks, is then that of a fitted model) is below this has converged, pixels: it is then
within about 1e-3 px of where more steps would take it."""
_FIT_SETTLED_PX = 1e-2
"""Largest last step of a fit that is kept, pixels (an unconverged corner that still moves
less than this is within that of the optimum)."""
_FIT_MAX_STEP_PX = 0.5
"""Largest move of a corner in one step, pixels."""
_FIT_MAX_TURN_RAD = 0.2
"""Largest turn of an edge line in one step, radians."""
_FIT_MAX_SHIFT_PX = 1.0
"""A fitted corner further than this from cornerSubPix's is not believed, pixels."""
_FIT_MIN_CROSSING = 0.1
"""Smallest sine of the angle between the two fitted edge lines (a corner seen nearly
edge-on has no defined crossing)."""
_FIT_MIN_CONTRAST_GREY = 10.0
"""Smallest fitted contrast b (half the difference of the squares' grey levels) of a fit
that is kept, grey levels."""
_FIT_RESIDUAL_RATIO = 3.0
"""A fit whose residuals' RMS exceeds this many times the median over the board's corners
is not kept: dirt or glare over the corner, which the model does not describe (the sensor
noise makes the residuals of the others alike, within 10-20 %)."""
_FIT_RESIDUAL_CONTRAST = 0.03
"""A fit whose residuals' RMS is below this fraction of its contrast b is kept whatever the
median (`_FIT_RESIDUAL_RATIO`): without noise the residuals are the 8-bit rounding, 0.2-0.8
grey levels, which a ratio alone would reject."""
_FIT_RIDGE = 1e-9
"""Relative ridge added to the normal equations so that a flat direction (sigma below one
tap) is left alone instead of making them singular."""


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


def detect_corners_quickly(image: np.ndarray, board: Checkerboard
                           ) -> np.ndarray | None | Unsure:
    """The corners (as `detect_corners`) from the cheap detectors alone, None when the fast
    check sees no board, or `UNSURE`.

    The look at half size that the daemon's checks take too (kernel.chessboard.quick_look:
    the fast check, then the classic detector), its corners then refined on the full image."""
    full = as_grey(image)
    look = quick_look(full, board.pattern_size, scale=0.5)
    if not look.board_seen:
        return None
    if look.corners_px is None:
        return UNSURE
    finished = _finished(full, look.corners_px, board)
    return UNSURE if finished is None else finished


def detect_corners_robustly(image: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """The corners (as `detect_corners`) from the classic detector at full size, or where it
    fails from the sector-based one (findChessboardCornersSB, 0.1-0.4 s, and as long to fail
    on a board cut by the image's edge), or None.

    The classic detector at full size finds most boards it missed at half size (of the 11
    the sector-based one found on the realistic lab's 140 poses, 10, in 5-16 ms instead of
    0.1-0.15 s, finished to the same corners within 3e-6 px); where it fails it costs
    45-80 ms more."""
    full = as_grey(image)
    smoothed = cv2.GaussianBlur(full, (0, 0), _DETECT_SMOOTH_PX)
    corners = classic_grid(smoothed, board.pattern_size)
    if corners is not None and (finished := _finished(full, corners, board)) is not None:
        return finished
    found, sb_corners = cv2.findChessboardCornersSB(full, board.pattern_size)
    return _finished(full, sb_corners.reshape(-1, 2), board) if found else None


def _finished(grey: np.ndarray, corners: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """Approximate corners (n, 2) in OpenCV's order, refined and put in rig order; None when
    the squares around the grid are not the print's outer ring (`_ring_is_printed`)."""
    ordered = _to_rig_order(grey, _refine(grey, corners.astype(np.float64), board), board)
    return ordered if _ring_is_printed(grey, ordered, board) else None


def _refine(grey: np.ndarray, corners: np.ndarray, board: Checkerboard) -> np.ndarray:
    """Corners refined by cornerSubPix, then by the fit of the blurred-corner model
    (`_fit_corners`); where that fit fails, fitted again from where the board's fitted
    corners around it put it (`_predicted`), and that prediction stands where it fails again.

    Why not cornerSubPix's corner there: on a noisy image its gradients are noise. With 30
    grey levels of noise (corners fitted to 0.09 px RMS) it is off by 0.3 px RMS and up to
    1.2 px, with a blur of 1.5 px and 20 grey levels by up to 1.9 px; the fit, started that far
    off, fails at 1-10 % of the corners, and those kept cornerSubPix's corner: boards off by
    0.5-5 px at single corners. The prediction from the neighbours is within about the fit's
    own noise, and from it the fit succeeds at most of them."""
    start = _subpix(grey, corners, board)
    fitted, ok = _fit_corners(grey, start, board)
    if ok.all() or ok.sum() < _MIN_PREDICTING:
        return np.where(ok[:, None], fitted, start)
    predicted = _predicted(fitted, ok, board)
    again, ok_again = _fit_corners(grey, np.where(ok[:, None], fitted, predicted), board)
    return np.where(ok[:, None], fitted, np.where(ok_again[:, None], again, predicted))


def fit_corners_from(grey: np.ndarray, starts: np.ndarray, board: Checkerboard
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Corners (n, 2) refined from `starts` (every corner of the board, rig order, pixels) as
    `_refine` refines a detector's, and a mask (n,) of those whose model fit succeeded: the
    others are not corners to believe (no fallback here, unlike `_refine`). For corners that
    no detector found, predicted instead (calibration.camera.recovered_views): a start
    outside the image (a board running off it) is not refined, and not kept."""
    height, width = grey.shape[:2]
    inside = np.all((starts >= 0) & (starts <= np.array([width - 1, height - 1])), axis=1)
    if not inside.any():
        return starts, inside
    fitted, ok = _fit_corners(grey, _subpix(grey, starts, board, inside), board)
    return fitted, ok & inside


_MIN_PREDICTING = 6
"""Fewest fitted corners a homography predicts a failed one from (4 determine it; a few more
average their noise)."""
_PREDICTING_REACH = 2
"""How many squares away (along X and Y) the fitted corners that predict a failed one may be:
close enough that the lens's distortion barely bends the grid over them."""


def _predicted(fitted: np.ndarray, ok: np.ndarray, board: Checkerboard) -> np.ndarray:
    """(n, 2) where the homography of the fitted corners (`ok`) within `_PREDICTING_REACH`
    squares of each corner puts it (of all the fitted corners where fewer than
    `_MIN_PREDICTING` are that close), pixels."""
    ix, iy = np.meshgrid(np.arange(board.corners_x), np.arange(board.corners_y))
    grid = np.column_stack([ix.ravel(), iy.ravel()]).astype(np.float64)
    predicted = fitted.copy()
    for k in np.flatnonzero(~ok):
        near = ok & (np.abs(grid - grid[k]).max(axis=1) <= _PREDICTING_REACH)
        use = near if near.sum() >= _MIN_PREDICTING else ok
        H, _ = cv2.findHomography(grid[use], fitted[use], 0)
        if H is not None:
            predicted[k] = cv2.perspectiveTransform(grid[None, k:k + 1], H)[0, 0]
    return predicted


def _subpix(grey: np.ndarray, corners: np.ndarray, board: Checkerboard,
            which: np.ndarray | None = None) -> np.ndarray:
    """Corners refined by cornerSubPix with a window sized to the smallest corner spacing
    (0.02-0.05 px RMS from the truth on the simulated images: the start of `_fit_corners`);
    only those of the mask `which` where given (the others as they are)."""
    grid = corners.reshape(board.corners_y, board.corners_x, 2)
    spacing = min(
        np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
        np.linalg.norm(np.diff(grid, axis=1), axis=2).min(),
    )
    half = int(np.clip(round(_SUBPIX_WINDOW_FRACTION * spacing), *_SUBPIX_HALF_WINDOW_PX))
    chosen = np.ones(len(corners), dtype=bool) if which is None else which
    refined = corners.astype(np.float64)
    refined[chosen] = cv2.cornerSubPix(
        grey,
        corners[chosen].astype(np.float32).reshape(-1, 1, 2),
        (half, half),
        (-1, -1),
        _SUBPIX_CRITERIA,
    ).reshape(-1, 2)
    return refined


def _fit_corners(grey: np.ndarray, corners: np.ndarray, board: Checkerboard
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Corners (n, 2) fitted by the blurred-corner model, and a mask (n,) of those where the
    fit succeeded (elsewhere the input corner is returned).

    The model of the grey level at the pixel centred on x, near a corner c and inside the four
    squares around it:

        I(x) = a + b [g_sigma * Q](x),   Q(x) = q(n_A . (x - c)) q(n_B . (x - c)),

    where n_A, n_B are the normals of the two edge lines through c (along the grid's X and
    Y), q(d) = clip(2 d, -1, 1) is the side of a line (-1 or +1) averaged over one pixel
    across it (d in pixels), so that Q is the checkerboard's pattern around c as pixels
    integrate it, and g_sigma is a Gaussian blur of sigma pixels applied on the pixel grid
    (taps at whole pixels, `_BLUR_TAPS` either side). That is exactly how sim.light renders a
    corner (each pixel integrated across the edges, then OpenCV's GaussianBlur), so the fit
    adds no bias of its own there, unlike estimators that interpolate the image
    (cornerSubPix's gradients; a point-symmetry or saddle-point criterion on a smoothed
    image, tried too): grey levels between pixel centres are not those of a smooth function,
    and such estimators lock onto the pixel grid by 0.002-0.05 px, depending on the corner's
    phase and on the edges' angles (worst near 45 degrees, where the pixel centres sample an
    edge's profile every 0.7 px). A camera forms the image a little differently (its lens
    blurs before the pixels integrate, over their whole square): on renders made that way
    (4x supersampled) the fit is off by 0.006-0.007 px RMS, cornerSubPix by 0.019-0.020 px.
    Perspective keeps the edge lines straight; the simulated lens's distortion bends them by
    at most 0.002 px over a window, at the image's corners. A gradient of light across the
    image shifts the fit by about 0.001 px per 20 % of brightness change across its width.

    The seven parameters per corner (c, the lines' angles, sigma, a and b) are fitted by
    weighted Gauss-Newton from the given corners and the grid's directions, all corners at
    once, on a disc of radius given by `_fit_radii` (tapered weights); a corner stops once its
    step is below `_FIT_TOLERANCE_PX`. A fit fails where the disc leaves the image, the
    squares around the corner are too small for a disc of `_FIT_HALF_WINDOW_PX[0]`, the
    steps do not settle, the edge lines come out nearly parallel or the contrast faint, the
    result moves by more than `_FIT_MAX_SHIFT_PX` from the input, or the model fits the
    pixels much worse than at the board's other corners (dirt or glare in a real image,
    `_FIT_RESIDUAL_RATIO`): there the input corner stands.
    """
    n = corners.shape[0]
    along_x, along_y, radius = _fit_radii(corners, board)
    ok = radius >= _FIT_HALF_WINDOW_PX[0]
    if not ok.any():
        return corners, ok
    half = int(np.ceil(radius[ok].max()))
    centre = np.rint(corners).astype(np.int64)
    ok &= _window_inside(grey.shape, centre, half)
    offsets = np.arange(-half, half + 1)
    h, w = grey.shape
    rows = np.clip(centre[:, 1, None, None] + offsets[None, :, None], 0, h - 1)
    cols = np.clip(centre[:, 0, None, None] + offsets[None, None, :], 0, w - 1)
    data = grey[rows, cols].astype(np.float32).reshape(n, -1, 1)
    start = corners - centre
    r2 = ((offsets[None, None, :] - start[:, 0, None, None]) ** 2
          + (offsets[None, :, None] - start[:, 1, None, None]) ** 2)
    weight = (np.clip(1.0 - r2 / np.maximum(radius, 1.0)[:, None, None] ** 2, 0.0, None) ** 2
              ).astype(np.float32).reshape(n, -1, 1)
    # parameters: corner offset from `centre` (2), normal angles of the lines along the grid's
    # X and Y (2), blur sigma, grey level a and contrast b
    params = np.column_stack([
        start,
        np.arctan2(along_x[:, 0], -along_x[:, 1]),
        np.arctan2(along_y[:, 0], -along_y[:, 1]),
        np.full(n, _BLUR_START_PX),
        np.zeros((n, 2)),
    ])
    step_px = np.full(n, np.inf)
    rms = np.full(n, np.inf)
    active = ok.copy()
    for iteration in range(_FIT_ITERATIONS):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        step, rms[idx] = _gauss_newton_step(data[idx], weight[idx], params[idx], half)
        if iteration >= _FIT_DAMPED_AFTER:
            step *= 0.5  # a corner still moving is likely swinging between two pixel phases
        step[:, :2] = np.clip(step[:, :2], -_FIT_MAX_STEP_PX, _FIT_MAX_STEP_PX)
        step[:, 2:4] = np.clip(step[:, 2:4], -_FIT_MAX_TURN_RAD, _FIT_MAX_TURN_RAD)
        params[idx] += step
        params[idx, 4] = np.clip(params[idx, 4], *_BLUR_RANGE_PX)
        step_px[idx] = np.hypot(step[:, 0], step[:, 1])
        active[idx] = (step_px[idx] >= _FIT_TOLERANCE_PX) | (iteration == 0)
    fitted = centre + params[:, :2]
    crossing = np.abs(np.sin(params[:, 2] - params[:, 3]))
    ok &= (step_px < _FIT_SETTLED_PX) & np.isfinite(fitted).all(axis=1)
    ok &= np.hypot(*(fitted - corners).T) <= _FIT_MAX_SHIFT_PX
    ok &= (crossing >= _FIT_MIN_CROSSING) & (np.abs(params[:, 6]) >= _FIT_MIN_CONTRAST_GREY)
    if ok.any():  # a corner the model fits much worse than the board's others is disturbed
        typical = _FIT_RESIDUAL_RATIO * np.median(rms[ok])
        ok &= rms <= np.maximum(typical, _FIT_RESIDUAL_CONTRAST * np.abs(params[:, 6]))
    return np.where(ok[:, None], fitted, corners), ok


def _fit_radii(corners: np.ndarray, board: Checkerboard
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid's local directions along X and Y at each corner ((n, 2) pixels per square,
    central differences) and the radius of the fit's disc (n,) pixels.

    The disc must stay inside the four squares around the corner, where the model holds: the
    corner's distance to the far sides of the four parallelograms its neighbours span (a
    neighbour missing at the grid's edge is mirrored: the outer squares are printed whole),
    less `_FIT_MARGIN_PX` for the blur, at most `_FIT_HALF_WINDOW_PX[1]` (the cost grows with
    its square; the noise falls only as its square root).
    """
    grid = corners.reshape(board.corners_y, board.corners_x, 2)
    step_x = np.diff(grid, axis=1)
    step_y = np.diff(grid, axis=0)
    forward_x = np.concatenate([step_x, step_x[:, -1:]], axis=1)
    back_x = -np.concatenate([step_x[:, :1], step_x], axis=1)
    forward_y = np.concatenate([step_y, step_y[-1:]], axis=0)
    back_y = -np.concatenate([step_y[:1], step_y], axis=0)
    room = np.full(grid.shape[:2], np.inf)
    for side_x in (forward_x, back_x):
        for side_y in (forward_y, back_y):
            area = np.abs(side_x[..., 0] * side_y[..., 1] - side_x[..., 1] * side_y[..., 0])
            longest = np.maximum(np.linalg.norm(side_x, axis=2), np.linalg.norm(side_y, axis=2))
            room = np.minimum(room, area / longest)
    along_x = (forward_x - back_x).reshape(-1, 2) / 2
    along_y = (forward_y - back_y).reshape(-1, 2) / 2
    radius = np.minimum(room.ravel() - _FIT_MARGIN_PX, _FIT_HALF_WINDOW_PX[1])
    return along_x, along_y, radius


def _window_inside(shape: tuple[int, ...], centre: np.ndarray, half: int) -> np.ndarray:
    """(n,) True where the square of half-size `half` around `centre` lies in the image."""
    h, w = shape[:2]
    return ((centre[:, 0] >= half) & (centre[:, 0] < w - half)
            & (centre[:, 1] >= half) & (centre[:, 1] < h - half))


def _gauss_newton_step(data: np.ndarray, weight: np.ndarray, params: np.ndarray, half: int
                       ) -> tuple[np.ndarray, np.ndarray]:
    """(n, 7) step of the parameters (see `_fit_corners`) for n corners' windows (data and
    weights (n, (2 half + 1)^2, 1)), and the weighted RMS (n,) of the residuals before the
    step, grey levels.

    The model is linear in a and b: they are first solved for with the other parameters
    fixed (so that the first step needs no start for them), then all seven take a
    Gauss-Newton step from there; the step returned includes both moves of a and b.
    """
    n = len(params)
    shape, derivatives = _corner_model(params, half)
    shape = shape.reshape(n, -1, 1)
    levels = np.concatenate([np.ones_like(shape), shape], axis=2)
    linear = _weighted_solve(levels, weight, data)
    contrast = linear[:, 1, None, None].astype(np.float32)
    jacobian = np.concatenate(
        [*(contrast * d.reshape(n, -1, 1) for d in derivatives), levels], axis=2)
    residual = data - (levels @ linear[..., None].astype(np.float32))
    step = _weighted_solve(jacobian, weight, residual)
    step[:, 5:] += linear - params[:, 5:]
    rms = np.sqrt((weight * residual**2).sum(axis=(1, 2)) / weight.sum(axis=(1, 2)))
    return step, rms


def _weighted_solve(design: np.ndarray, weight: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(n, k) weighted least-squares solutions of n systems design (n, m, k) x = target
    (n, m, 1) with weights (n, m, 1), with the relative ridge `_FIT_RIDGE`."""
    weighted = (design * weight).transpose(0, 2, 1)
    normal = (weighted @ design).astype(np.float64)
    rhs = (weighted @ target).astype(np.float64)
    k = design.shape[2]
    normal += _FIT_RIDGE * np.trace(normal, axis1=1, axis2=2)[:, None, None] * np.eye(k)
    return np.linalg.solve(normal, rhs)[..., 0]


def _corner_model(params: np.ndarray, half: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """The blurred corner g_sigma * Q on the window (n, 2 half + 1, 2 half + 1), and its
    derivatives with respect to the corner's offset (u, v), the two lines' normal angles and
    sigma (all float32).

    Q and the derivatives of Q (which the blur, being linear, carries over) are computed on the
    window grown by the blur's taps, then blurred by banded matrix products (rows, then
    columns), with each corner's own sigma.
    """
    n = len(params)
    grown = np.arange(-half - _BLUR_TAPS, half + _BLUR_TAPS + 1, dtype=np.float64)
    x = (grown[None, None, :] - params[:, 0, None, None]).astype(np.float32)
    y = (grown[None, :, None] - params[:, 1, None, None]).astype(np.float32)
    cos_a, sin_a, cos_b, sin_b = (
        f(params[:, k]).astype(np.float32)[:, None, None]
        for k, f in ((2, np.cos), (2, np.sin), (3, np.cos), (3, np.sin)))
    dist_a = cos_a * x + sin_a * y
    dist_b = cos_b * x + sin_b * y
    wave_a = np.clip(2 * dist_a, -1, 1)
    wave_b = np.clip(2 * dist_b, -1, 1)
    # d Q / d dist_a and d Q / d dist_b: the ramps' slope 2 inside a pixel of the line
    slope_a = np.where(np.abs(dist_a) < 0.5, 2 * wave_b, 0).astype(np.float32)
    slope_b = np.where(np.abs(dist_b) < 0.5, 2 * wave_a, 0).astype(np.float32)
    along_a = cos_a * y - sin_a * x  # d dist_a / d angle_a
    along_b = cos_b * y - sin_b * x
    sharp = np.stack([wave_a * wave_b, slope_a, slope_b, slope_a * along_a, slope_b * along_b],
                     axis=1)
    taps, taps_dsigma = _blur_taps(params[:, 4])
    size = grown.size
    blur = _banded(taps, size)
    blur_dsigma = _banded(taps_dsigma, size)
    rows = (sharp.reshape(n, -1, size) @ blur).reshape(n, 5, size, -1)
    blurred = blur.transpose(0, 2, 1)[:, None] @ rows
    shape = blurred[:, 0]
    dsigma = (blur_dsigma.transpose(0, 2, 1) @ rows[:, 0]
              + blur.transpose(0, 2, 1) @ (sharp[:, 0] @ blur_dsigma))
    du = -(cos_a * blurred[:, 1] + cos_b * blurred[:, 2])
    dv = -(sin_a * blurred[:, 1] + sin_b * blurred[:, 2])
    return shape, [du, dv, blurred[:, 3], blurred[:, 4], dsigma]


def _blur_taps(sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normalised Gaussian taps at -`_BLUR_TAPS`..`_BLUR_TAPS` pixels for each sigma (n,)
    (OpenCV's GaussianBlur kernel, as sim.light uses), and their derivatives by sigma."""
    j = np.arange(-_BLUR_TAPS, _BLUR_TAPS + 1, dtype=np.float64)
    e = np.exp(-0.5 * j * j / sigma[:, None] ** 2)
    de = e * j * j / sigma[:, None] ** 3
    total = e.sum(axis=1, keepdims=True)
    return e / total, de / total - e * de.sum(axis=1, keepdims=True) / total**2


def _banded(taps: np.ndarray, size: int) -> np.ndarray:
    """(n, size, size - 2 T) float32 matrices that correlate a row of `size` samples with each
    corner's taps (n, 2 T + 1), keeping the outputs whose taps all fall inside the row."""
    n, width = taps.shape
    out = size - width + 1
    band = np.zeros((n, size, out), dtype=np.float32)
    tap, k = np.meshgrid(np.arange(width), np.arange(out), indexing="ij")
    band[:, tap + k, k] = taps[:, tap]
    return band


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


RING_MIN_CONTRAST = 0.5
"""Least alternation, as a fraction of the pattern's own, of the squares on each side of the
ring outside the inner corners (`_ring_is_printed`)."""


def _ring_is_printed(grey: np.ndarray, corners: np.ndarray, board: Checkerboard) -> bool:
    """Whether the squares just outside the found grid alternate as the print's outer ring
    does, on every side of the grid that lies inside the image.

    Why: a board cut by the image's edge can show the detectors a grid of the right size that
    is shifted by one row or column: the pattern's outer edge, where its dark squares meet the
    white plate, looks like a row of inner corners (seen on the realistic lab: a camera's
    board 300 px off its true corners, which the colour check cannot tell, as one shift
    keeps the colours). Every printed pattern has a ring of squares around its inner corners
    ((corners_x + 1) x (corners_y + 1) squares); beyond a shifted grid one side shows the plate
    instead, whose squares do not alternate. Alternation is measured between neighbouring
    squares (half the expected-sign difference of their grey levels), so that light falling
    off across the board does not count; each side's must reach `RING_MIN_CONTRAST` of the
    pattern's inner one.
    """
    ny, nx = board.corners_y, board.corners_x
    grid = corners.reshape(ny, nx, 2)
    # one more row and column of corners on every side, extrapolated (locally affine)
    rows = np.concatenate([2 * grid[:1] - grid[1:2], grid, 2 * grid[-1:] - grid[-2:-1]], axis=0)
    full = np.concatenate([2 * rows[:, :1] - rows[:, 1:2], rows,
                           2 * rows[:, -1:] - rows[:, -2:-1]], axis=1)
    centres = (full[:-1, :-1] + full[1:, :-1] + full[:-1, 1:] + full[1:, 1:]) / 4
    h, w = grey.shape
    inside = ((centres[..., 0] >= 0) & (centres[..., 0] <= w - 1)
              & (centres[..., 1] >= 0) & (centres[..., 1] <= h - 1))
    u = np.clip(np.rint(centres[..., 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(centres[..., 1]).astype(int), 0, h - 1)
    level = grey[v, u].astype(np.float64)
    j, i = np.indices(level.shape) - 1  # square (i, j) of sim.light's print: the ring is -1
    sign = np.where((i + j) % 2 == (0 if board.origin_dark else 1), -1.0, 1.0)
    if board.marker_square is not None:
        mi, mj = board.marker_square
        sign[mj + 1, mi + 1] = np.nan  # its centre shows the other colour: left out

    def alternation(signs: np.ndarray, levels: np.ndarray, seen: np.ndarray) -> float:
        """Mean of sign_k (level_k - level_k+1) / 2 over neighbours along the last axis."""
        pair = seen[..., :-1] & seen[..., 1:] & np.isfinite(signs[..., :-1] + signs[..., 1:])
        steps = signs[..., :-1] * (levels[..., :-1] - levels[..., 1:]) / 2
        return float(steps[pair].mean()) if pair.any() else np.nan

    inner = (slice(1, -1), slice(1, -1))
    contrast = alternation(sign[inner], level[inner], inside[inner])
    if not contrast > 0:
        return False
    sides = [(sign[0], level[0], inside[0]), (sign[-1], level[-1], inside[-1]),
             (sign[:, 0], level[:, 0], inside[:, 0]), (sign[:, -1], level[:, -1], inside[:, -1])]
    for signs, levels, seen in sides:
        ring = alternation(signs, levels, seen)
        if np.isfinite(ring) and ring < RING_MIN_CONTRAST * contrast:
            return False
    return True


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
