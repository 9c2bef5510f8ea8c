"""Camera calibration from the session's checkerboard images (paper sections II and IV-D).

Steps: find the checkerboard's inner corners in every image, put them in the rig frame's
order, fit each camera's intrinsics and distortion (OpenCV's 5 coefficients, the paper's
equation 4) with one board pose per image, give every pose a covariance, and find each
camera's transform from the camera-0 frame from the views it shares with other cameras.

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
half-size image (1-2 ms when the board is there), and the robust sector-based detector
(findChessboardCornersSB, 0.1-0.2 s) at full size only when that fails. The corners are then
refined with cornerSubPix on the full-resolution image (about 0.05 px RMS on the
simulated images, against 0.07 px with occasional 0.5 px outliers from findChessboardCornersSB
alone).
"""

from __future__ import annotations

import contextlib
import threading
from collections import OrderedDict, deque
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from acquisition.rig_description import KnownIntrinsics, RigDescription
from acquisition.session import SessionReader

from ._cores import default_workers

_DETECTION_TIERS = (("classic", 0.5), ("sb", 1.0))
"""Detector and image scale of each attempt, cheapest first: the classic detector at half size
finds the boards of the simulated sessions in 1-2 ms (at quarter size it misses some, and its
fast check rejects boards); the sector-based detector at full size (0.1-0.2 s) is the robust
fallback, for small and distant boards."""
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
_CALIB_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-12)
_OPENCV_THREADS_LOCK = threading.Lock()


@contextlib.contextmanager
def _reproducible() -> Iterator[None]:
    """OpenCV on one thread for the block: calibrateCamera's parallel sums otherwise differ
    in the last bits from run to run, and so would every calibration that follows from them
    (a resumed capture could not be compared with an uninterrupted one). Its cost is small:
    the fits take milliseconds."""
    with _OPENCV_THREADS_LOCK:
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            yield
        finally:
            cv2.setNumThreads(threads)
MIN_VIEWS = 4
"""Fewest board views per camera for calibrateCamera: 9 intrinsic and distortion unknowns from
planar views need several orientations (one view fixes at most two intrinsics)."""
MIN_SHARED_VIEWS = 2
"""Fewest views two cameras must share to fit the transform between them."""


class CameraCalibrationError(ValueError):
    """The images cannot calibrate the cameras (too few views with a detectable board)."""


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


@dataclass(frozen=True)
class Pose:
    """A rigid transform x_to = R(rvec) x_from + tvec with the covariance of its parameters.

    Attributes:
        rvec: (3,) rotation vector, radians (OpenCV's Rodrigues convention).
        tvec: (3,) translation, metres.
        cov: (6, 6) covariance of (rvec, tvec) in rad^2, rad m, m^2.
    """

    rvec: np.ndarray
    tvec: np.ndarray
    cov: np.ndarray

    @property
    def R(self) -> np.ndarray:
        return cv2.Rodrigues(self.rvec)[0]

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform points of shape (..., 3)."""
        return np.asarray(points) @ self.R.T + self.tvec


@dataclass(frozen=True)
class BoardView:
    """One image in which the board was found.

    Attributes:
        camera: camera name ("cam0", ...).
        step: session step of the image ("pose/0003", "refmic").
        corners_px: (n_corners, 2) refined corner pixels in rig order (X fastest).
        rig_to_cam: the board pose in this camera's frame; its covariance comes from the
            Jacobian of the reprojection scaled by this image's residual variance, and includes
            the uncertainty of the camera's intrinsics (see `_pose_covariances`).
        rms_px: RMS reprojection error of the image's corners, pixels.
    """

    camera: str
    step: str
    corners_px: np.ndarray
    rig_to_cam: Pose
    rms_px: float


@dataclass(frozen=True)
class CameraIntrinsics:
    """One camera's intrinsics.

    Attributes:
        name: camera name.
        width, height: image size, pixels.
        K: (3, 3) intrinsic matrix, pixels.
        dist: (5,) distortion (k1, k2, p1, p2, k3), OpenCV's order.
        cov: (9, 9) covariance of (fx, fy, cx, cy, k1, k2, p1, p2, k3), pixels and unitless.
        rms_px: RMS reprojection error over all the camera's views, pixels.
        n_views: images used.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    cov: np.ndarray
    rms_px: float
    n_views: int

    @property
    def std(self) -> np.ndarray:
        """(9,) standard deviations of (fx, fy, cx, cy, k1, k2, p1, p2, k3)."""
        return np.sqrt(np.diag(self.cov))


@dataclass(frozen=True)
class Extrinsics:
    """A camera's transform from the camera-0 frame: x_cam = R x_cam0 + t.

    Attributes:
        R: (3, 3) rotation.
        t: (3,) translation, metres.
        rms_px: RMS reprojection error of the shared views used to fit it (0 for camera 0).
        n_shared_views: board views the fit used (0 for camera 0).
        via: the camera it was fitted against (itself for camera 0).
    """

    R: np.ndarray
    t: np.ndarray
    rms_px: float
    n_shared_views: int
    via: str

    def inverse_apply(self, points: np.ndarray) -> np.ndarray:
        """Points (..., 3) from this camera's frame into the camera-0 frame."""
        return (np.asarray(points) - self.t) @ self.R


@dataclass(frozen=True)
class MissedImage:
    """An image that was skipped, and why."""

    camera: str
    step: str
    reason: str


@dataclass(frozen=True)
class CameraCalibration:
    """Every camera's intrinsics, every board view and the cameras' transforms from camera 0.

    Attributes:
        board: the checkerboard.
        intrinsics: calibrated cameras by name, camera 0 first.
        cam_from_cam0: transform from the camera-0 frame of every camera linked to camera 0
            through shared views (camera 0 itself: the identity).
        views: board views by (camera, step), calibrated cameras only.
        missed: images without a detectable board, reported and skipped.
        uncalibrated: cameras left out, with the reason.
    """

    board: Checkerboard
    intrinsics: dict[str, CameraIntrinsics]
    cam_from_cam0: dict[str, Extrinsics]
    views: dict[tuple[str, str], BoardView]
    missed: list[MissedImage]
    uncalibrated: dict[str, str]

    @property
    def reference_camera(self) -> str:
        """The camera whose frame is the calibration's frame (camera 0)."""
        return next(iter(self.intrinsics))

    def views_of_step(self, step: str) -> list[BoardView]:
        """The step's views by calibrated cameras, in camera order."""
        return [self.views[(c, step)] for c in self.intrinsics if (c, step) in self.views]


# ---------------------------------------------------------------------------------------------
# Detection


def detect_corners(image: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """The board's inner corners in rig order (X fastest), (n_corners, 2) pixels, or None.

    Args:
        image: uint8 grey (h, w) or BGR (h, w, 3) image.
        board: the checkerboard to look for.
    """
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    corners = _find_corners(grey, board)
    if corners is None:
        return None
    corners = _refine(grey, corners, board)
    return _to_rig_order(grey, corners, board)


def _find_corners(grey: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """Approximate corners (n, 2) in OpenCV's order at full resolution, or None.

    cv2.checkChessboard (the detector's own fast check) rejects most images without a board:
    at half size first (about 1 ms), at full size (about 9 ms) only when that fails (it
    misses 2-4 % of the boards the detector then finds); then `_DETECTION_TIERS` are tried
    in turn, cheapest first.
    """
    half = cv2.resize(grey, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    if not (cv2.checkChessboard(half, board.pattern_size)
            or cv2.checkChessboard(grey, board.pattern_size)):
        return None
    for detector, scale in _DETECTION_TIERS:
        small = grey if scale == 1.0 else half if scale == 0.5 else cv2.resize(
            grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        if detector == "classic":
            found, corners = cv2.findChessboardCorners(
                small, board.pattern_size, flags=_CLASSIC_FLAGS
            )
        else:
            found, corners = cv2.findChessboardCornersSB(small, board.pattern_size)
        if found:
            # Pixel centres: full = (small + 1/2) / scale - 1/2 (INTER_AREA averages blocks).
            return (corners.reshape(-1, 2) + 0.5) / scale - 0.5
    return None


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


# ---------------------------------------------------------------------------------------------
# Calibration


Detection = tuple[np.ndarray | None, tuple[int, int]]
"""The corners found in an image (None: no board) and the image's (width, height)."""

DETECTION_CACHE_SIZE = 20_000
"""Images whose detections `calibrate_session` remembers (about 1 kB each)."""

_detections: OrderedDict[tuple[str, Checkerboard], Detection] = OrderedDict()
_detections_lock = threading.Lock()


def _detect(image: np.ndarray, board: Checkerboard) -> Detection:
    return detect_corners(image, board), image.shape[1::-1]


def calibrate_session(
    reader: SessionReader,
    board: Checkerboard,
    cameras: list[str],
    known: dict[str, KnownIntrinsics] | None = None,
    min_views: int = MIN_VIEWS,
    min_shared_views: int = MIN_SHARED_VIEWS,
) -> CameraCalibration:
    """Calibrate every camera of a session from all its checkerboard images.

    Every completed step with camera images ("pose/<nnnn>" and "refmic") is used: each is a
    board view that constrains the intrinsics. The detections are remembered by the image
    file's SHA-256 (session files never change once written), so that a long-running process
    (the calibration worker, whose live jobs see the same images again with a few more poses
    each time) decodes and searches each image once.

    Args:
        reader: the session.
        board: its checkerboard (`Checkerboard.of_rig`).
        cameras: camera names, camera 0 first.
        known: intrinsics known from elsewhere, by camera name (see `calibrate_detections`).

    Raises:
        CameraCalibrationError: camera 0 has too few views with a board.
    """
    files = {(camera, step): record.files[f"{camera}.png"]
             for step, record in sorted(reader.steps().items())
             for camera in cameras if f"{camera}.png" in record.files}
    with _detections_lock:
        remembered = {key: _detections.get((file.sha256, board)) for key, file in files.items()}
    new = [key for key, found in remembered.items() if found is None]

    def detect(key: tuple[str, str]) -> Detection:
        camera, step = key
        return _detect(reader.read_image(step, f"{camera}.png"), board)

    # PNG decoding and OpenCV's search release the interpreter lock: one image per core
    with ThreadPoolExecutor(default_workers()) as pool:
        detected = dict(zip(new, pool.map(detect, new), strict=True))
    with _detections_lock:
        for key, found in detected.items():
            _detections[(files[key].sha256, board)] = found
        for key in files:
            _detections.move_to_end((files[key].sha256, board))
        while len(_detections) > DETECTION_CACHE_SIZE:
            _detections.popitem(last=False)
    detections = {key: remembered[key] or detected[key] for key in files}
    return calibrate_detections(detections, cameras, board, min_views, min_shared_views, known)


def calibrate_images(
    images: dict[tuple[str, str], np.ndarray],
    cameras: list[str],
    board: Checkerboard,
    min_views: int = MIN_VIEWS,
    min_shared_views: int = MIN_SHARED_VIEWS,
    known: dict[str, KnownIntrinsics] | None = None,
) -> CameraCalibration:
    """Calibrate cameras from images keyed by (camera, step) (see `calibrate_detections`)."""
    with ThreadPoolExecutor(default_workers()) as pool:  # OpenCV releases the lock
        found = list(pool.map(lambda image: _detect(image, board), images.values()))
    return calibrate_detections(dict(zip(images, found, strict=True)), cameras, board,
                                min_views, min_shared_views, known)


def calibrate_detections(
    detections: dict[tuple[str, str], Detection],
    cameras: list[str],
    board: Checkerboard,
    min_views: int = MIN_VIEWS,
    min_shared_views: int = MIN_SHARED_VIEWS,
    known: dict[str, KnownIntrinsics] | None = None,
) -> CameraCalibration:
    """Calibrate cameras from the corners found in their images, keyed by (camera, step).

    Args:
        detections: corners (None: no board, reported in `missed`) and image size per image.
        cameras: camera names, camera 0 (the reference frame) first.
        board: the checkerboard.
        min_views: fewest views a camera needs; cameras other than camera 0 with fewer are
            reported in `uncalibrated`. A camera with known intrinsics needs one view.
        min_shared_views: fewest views two cameras must share to link their frames.
        known: intrinsics known from elsewhere, by camera name: "fixed" ones are used as
            given (the board poses are fitted with them), a "prior" is combined with the
            images' own fit, each weighted by its information (see `_combine_with_prior`).

    Raises:
        CameraCalibrationError: camera 0 has fewer than `min_views` views with a board.
    """
    known = known or {}
    corners: dict[tuple[str, str], np.ndarray] = {}
    missed = []
    for (camera, step), (found, _) in detections.items():
        if found is None:
            missed.append(MissedImage(camera, step, "no checkerboard found"))
        else:
            corners[(camera, step)] = found
    intrinsics: dict[str, CameraIntrinsics] = {}
    views: dict[tuple[str, str], BoardView] = {}
    uncalibrated: dict[str, str] = {}
    for camera in cameras:
        own = {step: c for (cam, step), c in corners.items() if cam == camera}
        needed = 1 if camera in known else min_views
        if len(own) < needed:
            reason = (
                f"the board was found in {len(own)} of its images, fewer than the {needed} "
                "needed to fit intrinsics and distortion"
            )
            if camera == cameras[0]:
                raise CameraCalibrationError(
                    f"cannot calibrate {camera}, the reference camera: {reason}; capture more "
                    "rig poses with the whole checkerboard in view"
                )
            uncalibrated[camera] = reason
            continue
        size = _image_size(detections, camera)
        intrinsics[camera], camera_views = _calibrate_camera(camera, own, size, board,
                                                             known.get(camera), min_views)
        views.update({(camera, v.step): v for v in camera_views})
    extrinsics = _link_cameras(intrinsics, views, board, min_shared_views)
    for camera in intrinsics:
        if camera not in extrinsics:
            uncalibrated[camera] = (
                f"shares fewer than {min_shared_views} board views with the cameras linked to "
                f"{cameras[0]}"
            )
    linked = {c: i for c, i in intrinsics.items() if c in extrinsics}
    views = {k: v for k, v in views.items() if k[0] in extrinsics}
    return CameraCalibration(board, linked, extrinsics, views, missed, uncalibrated)


def _image_size(detections: dict[tuple[str, str], Detection], camera: str) -> tuple[int, int]:
    """(width, height) of a camera's images, checked to be the same for all of them."""
    sizes = {size for (cam, _), (_, size) in detections.items() if cam == camera}
    if len(sizes) != 1:
        raise CameraCalibrationError(f"{camera}'s images differ in size: {sorted(sizes)}")
    return sizes.pop()


def _calibrate_camera(
    camera: str, corners: dict[str, np.ndarray], size: tuple[int, int], board: Checkerboard,
    known: KnownIntrinsics | None = None, min_views: int = MIN_VIEWS,
) -> tuple[CameraIntrinsics, list[BoardView]]:
    """calibrateCamera on one camera's views (or its known intrinsics), then the covariances
    and errors of the fit."""
    steps = sorted(corners)
    obj = board.object_points().astype(np.float32)
    image_points = [corners[s].astype(np.float32).reshape(-1, 1, 2) for s in steps]
    if known is not None and (known.use == "fixed" or len(steps) < min_views):
        K, dist = np.array(known.camera_matrix), np.array(known.distortion)
        intrinsics_cov = (np.diag(np.square(known.std)) if known.std is not None
                          else np.zeros((9, 9)))
        fits = _fits_with(K, dist, corners, steps, board)
    else:
        flags = cv2.CALIB_USE_INTRINSIC_GUESS if known is not None else 0
        K0 = np.array(known.camera_matrix) if known is not None else None
        d0 = np.array(known.distortion) if known is not None else None
        with _reproducible():
            _, K, dist, rvecs, tvecs = cv2.calibrateCamera(
                [obj] * len(steps), image_points, size, K0, d0, flags=flags,
                criteria=_CALIB_CRITERIA
            )
        dist = dist.ravel()[:5]
        fits = [
            _view_fit(corners[s], r.ravel(), t.ravel(), K, dist, board)
            for s, r, t in zip(steps, rvecs, tvecs, strict=True)
        ]
        intrinsics_cov = np.linalg.inv(_intrinsics_information(fits))
        if known is not None:
            K, dist, intrinsics_cov = _combine_with_prior(K, dist, intrinsics_cov, known)
            fits = _fits_with(K, dist, corners, steps, board)
    pose_covs = _pose_covariances(fits, intrinsics_cov)
    views = [
        BoardView(camera, s, corners[s], Pose(f.rvec, f.tvec, cov), f.rms_px)
        for s, f, cov in zip(steps, fits, pose_covs, strict=True)
    ]
    rms = float(np.sqrt(np.mean([f.rms_px**2 for f in fits])))
    intr = CameraIntrinsics(camera, size[0], size[1], K, dist, intrinsics_cov, rms, len(steps))
    return intr, views


def _fits_with(K: np.ndarray, dist: np.ndarray, corners: dict[str, np.ndarray],
               steps: list[str], board: Checkerboard) -> list[_ViewFit]:
    """Every view's board pose fitted with the given intrinsics (solvePnP), and its fit."""
    obj = board.object_points()
    fits = []
    for s in steps:
        ok, rvec, tvec = cv2.solvePnP(obj, corners[s].reshape(-1, 1, 2), K, dist,
                                      flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise CameraCalibrationError(f"no board pose fits the corners of {s} with the "
                                         "known intrinsics; check the intrinsics file")
        fits.append(_view_fit(corners[s], rvec.ravel(), tvec.ravel(), K, dist, board))
    return fits


def _combine_with_prior(K: np.ndarray, dist: np.ndarray, cov: np.ndarray,
                        known: KnownIntrinsics) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The images' intrinsics combined with a prior, each weighted by its information
    (the linearized maximum a posteriori: x = (S + P)^-1 (S x_images + P x_prior), with S the
    images' information and P = diag(1 / std^2) the prior's); its covariance (S + P)^-1."""
    x_images = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *dist])
    Kp = np.array(known.camera_matrix)
    x_prior = np.array([Kp[0, 0], Kp[1, 1], Kp[0, 2], Kp[1, 2], *known.distortion])
    S = np.linalg.inv(cov)
    P = np.diag(1.0 / np.square(known.std))  # type: ignore[arg-type]
    combined_cov = np.linalg.inv(S + P)
    x = combined_cov @ (S @ x_images + P @ x_prior)
    K_new = np.array([[x[0], 0.0, x[2]], [0.0, x[1], x[3]], [0.0, 0.0, 1.0]])
    return K_new, x[4:], combined_cov


@dataclass(frozen=True)
class _ViewFit:
    """One view's pose and the Jacobians of its reprojection at the fitted parameters.

    Attributes:
        rvec, tvec: the pose (rig to camera).
        J_pose: (2 n, 6) derivatives of the pixel coordinates by (rvec, tvec).
        J_intr: (2 n, 9) derivatives by (fx, fy, cx, cy, k1, k2, p1, p2, k3).
        s2: residual variance per pixel coordinate, px^2 (sum of squares / (2 n - 6)).
        rms_px: RMS reprojection error per corner, pixels.
    """

    rvec: np.ndarray
    tvec: np.ndarray
    J_pose: np.ndarray
    J_intr: np.ndarray
    s2: float
    rms_px: float


def _view_fit(
    corners: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    K: np.ndarray,
    dist: np.ndarray,
    board: Checkerboard,
) -> _ViewFit:
    """Reprojection residuals and Jacobians of one view (cv2.projectPoints)."""
    projected, jac = cv2.projectPoints(board.object_points(), rvec, tvec, K, dist)
    residual = corners - projected.reshape(-1, 2)
    sq = float(np.sum(residual**2))
    return _ViewFit(
        rvec=rvec,
        tvec=tvec,
        J_pose=jac[:, :6],
        J_intr=jac[:, 6:15],
        s2=sq / (residual.size - 6),
        rms_px=float(np.sqrt(sq / len(residual))),
    )


def _intrinsics_information(fits: list[_ViewFit]) -> np.ndarray:
    """Information matrix (9, 9) of the intrinsics in the joint fit of all views, the poses
    marginalized out.

    The information matrix of the joint fit, each view weighted by its own residual variance
    s_i^2 (a blurred image counts less), is [[U, W], [W^T, V]] with V block-diagonal:
    V_i = J_i^T J_i / s_i^2, W_i = C_i^T J_i / s_i^2, U = sum C_i^T C_i / s_i^2 (J: pose
    Jacobian, C: intrinsics Jacobian). The intrinsics' information is the Schur complement
    S = U - sum W_i V_i^-1 W_i^T (its inverse their covariance).
    """
    S = sum(f.J_intr.T @ f.J_intr / f.s2 for f in fits)
    for f in fits:
        W = f.J_intr.T @ f.J_pose / f.s2
        S = S - W @ np.linalg.inv(f.J_pose.T @ f.J_pose / f.s2) @ W.T
    return S


def _pose_covariances(fits: list[_ViewFit], intrinsics_cov: np.ndarray) -> list[np.ndarray]:
    """Each pose's marginal covariance (6, 6): V_i^-1 + V_i^-1 W_i^T C W_i V_i^-1, its own
    noise plus the intrinsics' uncertainty C (notation of `_intrinsics_information`).

    Why the second term: a focal-length error scales every pose's depth; left out, the
    covariance claims depths several times better than they are. (The intrinsics' errors also
    correlate the poses with each other; those cross terms are not returned.)
    """
    covs = []
    for f in fits:
        V_inv = np.linalg.inv(f.J_pose.T @ f.J_pose / f.s2)
        W = f.J_intr.T @ f.J_pose / f.s2
        covs.append(V_inv + V_inv @ W.T @ intrinsics_cov @ W @ V_inv)
    return covs


# ---------------------------------------------------------------------------------------------
# Camera-to-camera transforms


def _link_cameras(
    intrinsics: dict[str, CameraIntrinsics],
    views: dict[tuple[str, str], BoardView],
    board: Checkerboard,
    min_shared_views: int,
) -> dict[str, Extrinsics]:
    """Each camera's transform from camera 0, breadth-first through shared views.

    A camera that shares no views with camera 0 is still linked through a camera that does
    (cameras around a sphere may each overlap only with their neighbours).
    """
    cameras = list(intrinsics)
    reference = cameras[0]
    linked = {reference: Extrinsics(np.eye(3), np.zeros(3), 0.0, 0, reference)}
    queue = deque([reference])
    while queue:
        known = queue.popleft()
        for camera in cameras:
            if camera in linked:
                continue
            shared = _shared_steps(views, known, camera)
            if len(shared) < min_shared_views:
                continue
            R, t, rms = _stereo(intrinsics[known], intrinsics[camera], views, shared, board)
            base = linked[known]
            linked[camera] = Extrinsics(R @ base.R, R @ base.t + t, rms, len(shared), known)
            queue.append(camera)
    return {c: linked[c] for c in cameras if c in linked}


def _shared_steps(views: dict[tuple[str, str], BoardView], a: str, b: str) -> list[str]:
    steps_a = {s for c, s in views if c == a}
    return sorted(s for c, s in views if c == b and s in steps_a)


def _stereo(
    first: CameraIntrinsics,
    second: CameraIntrinsics,
    views: dict[tuple[str, str], BoardView],
    steps: list[str],
    board: Checkerboard,
) -> tuple[np.ndarray, np.ndarray, float]:
    """R, t (x_second = R x_first + t) and RMS error from stereoCalibrate, intrinsics fixed.

    Fitting the transform to the corners of both images of every shared view weighs each
    view by how well it constrains the transform, unlike averaging per-view pose differences.
    """
    obj = board.object_points().astype(np.float32)
    pts_a = [views[(first.name, s)].corners_px.astype(np.float32) for s in steps]
    pts_b = [views[(second.name, s)].corners_px.astype(np.float32) for s in steps]
    with _reproducible():
        rms, *_, R, t, _, _ = cv2.stereoCalibrate(
            [obj] * len(steps),
            pts_a,
            pts_b,
            first.K,
            first.dist,
            second.K,
            second.dist,
            (first.width, first.height),
            flags=cv2.CALIB_FIX_INTRINSIC,
            criteria=_CALIB_CRITERIA,
        )
    return R, t.ravel(), float(rms)
