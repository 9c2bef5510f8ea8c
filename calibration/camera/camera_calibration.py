"""Camera calibration from the session's checkerboard images (paper sections II and IV-D).

Steps: find the checkerboard's inner corners in every image, put them in the rig frame's
order, fit each camera's intrinsics and distortion (OpenCV's 5 coefficients, the paper's
equation 4) with one board pose per image, give every pose a covariance, and find each
camera's transform from the camera-0 frame from the views it shares with other cameras.
The images' mistakes (a board hidden, blurred, in glare; MJPEG) are looked for in every
image (calibration.camera.image_checks); views whose corners cannot be trusted are left out and the
cameras calibrated again without them. A board that bows out of its plane significantly
(calibration.camera.board_bow) has the cameras calibrated once more with its sagged corners, so
that the bow's misfit is not taken for corner noise.

The board and its corner detection (frames, orders, the detectors) are calibration.camera.corners;
a board pose maps rig coordinates into the camera's: x_cam = R(rvec) x_rig + t.
"""

from __future__ import annotations

import contextlib
import threading
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from acquisition.contracts.rig_description import KnownIntrinsics
from acquisition.contracts.session import SessionReader
from kernel.rigid import RigidTransform

from .._blas import single_threaded_blas
from .._cores import default_workers
from .board_bow import BoardBow, CameraViews, board_points, estimate_bow
from .corner_noise import CornerNoise, estimate_corner_noise
from .corners import (
    Checkerboard,
    Unsure,
    detect_corners_quickly,
    detect_corners_robustly,
)
from ..errors import CalibrationInputError
from .image_checks import ImageCheckMemo, ViewImage, check_images
from ..memo import LruMemo
from ..result import Finding

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


class CameraCalibrationError(CalibrationInputError):
    """The images cannot calibrate the cameras (too few views with a detectable board)."""


@dataclass(frozen=True)
class Pose:
    """A fitted rigid transform and the covariance of its parameters; the field that holds
    it names the direction (`BoardView.rig_to_cam`, `RigPoseInCam0.rig_to_cam0`).

    The covariance is not part of `RigidTransform`: composing or inverting a transform does
    not carry it (that needs the Jacobians, see `speakers._to_cam0`), and most transforms
    have none.

    Attributes:
        transform: x_to = R x_from + t, made from the fitted rotation vector
            (`RigidTransform.from_rotvec`, which keeps it bit for bit and on its branch).
        cov: (6, 6) covariance of `transform.params` = (rotvec, t) in rad^2, rad m, m^2.
    """

    transform: RigidTransform
    cov: np.ndarray


@dataclass(frozen=True)
class BoardView:
    """One image in which the board was found.

    Attributes:
        camera: camera name ("cam0", ...).
        step: session step of the image ("pose/0003", "refmic").
        corners_px: (n_corners, 2) refined corner pixels in rig order (X fastest); NaN
            where a view recovered in part lacks a corner (`partial_view`).
        rig_to_cam: the board pose in this camera's frame; its covariance comes from the
            Jacobian of the reprojection scaled by the view's corner noise (`sigma_px`), and
            includes the uncertainty of the camera's intrinsics (see `_pose_covariances`).
        rms_px: RMS reprojection error of the image's corners, pixels.
        sigma_px: the corner noise of the view per pixel coordinate (its camera's, or its
            own where it differs: `CornerNoise.view_sigma_px`), pixels.
    """

    camera: str
    step: str
    corners_px: np.ndarray
    rig_to_cam: Pose
    rms_px: float
    sigma_px: float


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
        noise: the corner noise estimated from the camera calibration's residuals.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    cov: np.ndarray
    rms_px: float
    n_views: int
    noise: CornerNoise

    @property
    def std(self) -> np.ndarray:
        """(9,) standard deviations of (fx, fy, cx, cy, k1, k2, p1, p2, k3)."""
        return np.sqrt(np.diag(self.cov))


@dataclass(frozen=True)
class Extrinsics:
    """A camera's transform from the camera-0 frame and how it was fitted.

    Attributes:
        cam0_to_cam: x_cam = R x_cam0 + t, metres.
        rms_px: RMS reprojection error of the shared views used to fit it (0 for camera 0).
        n_shared_views: board views the fit used (0 for camera 0).
        via: the camera it was fitted against (itself for camera 0).
    """

    cam0_to_cam: RigidTransform
    rms_px: float
    n_shared_views: int
    via: str


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
        findings: the images' mistakes found (calibration.image_checks).
        bow: the board's sag out of its plane (calibration.camera.board_bow), estimated from every
            camera with `MIN_VIEWS` views (None: not estimated, or no such camera). Where it is
            significant, the intrinsics and the views were fitted with the sagged corners
            (`board_points`).
    """

    board: Checkerboard
    intrinsics: dict[str, CameraIntrinsics]
    cam_from_cam0: dict[str, Extrinsics]
    views: dict[tuple[str, str], BoardView]
    missed: list[MissedImage]
    uncalibrated: dict[str, str]
    findings: list[Finding] = field(default_factory=list)
    bow: BoardBow | None = None

    def board_points(self) -> np.ndarray:
        """(n_corners, 3) the board's inner corners in the rig frame the cameras were calibrated
        with (calibration.camera.board_bow.board_points): every use of the board poses needs
        these, metres."""
        return board_points(self.board, self.bow)

    @property
    def reference_camera(self) -> str:
        """The camera whose frame is the calibration's frame (camera 0)."""
        return next(iter(self.intrinsics))

    def views_of_step(self, step: str) -> list[BoardView]:
        """The step's views by calibrated cameras, in camera order."""
        return [self.views[(c, step)] for c in self.intrinsics if (c, step) in self.views]


# ---------------------------------------------------------------------------------------------
# Calibration


Detection = tuple[np.ndarray | None, tuple[int, int]]
"""The corners found in an image (None: no board) and the image's (width, height)."""

DETECTION_CACHE_SIZE = 20_000
"""Images whose detections a worker's `DetectionMemo` remembers (about 1 kB each)."""

QuickFind = tuple[np.ndarray | None | Unsure, tuple[int, int]]
"""The quick detectors' answer for an image (corners, None: no board, or Unsure) and the
image's (width, height)."""

DetectionMemo = LruMemo[tuple[str, Checkerboard, str], QuickFind]
"""What the detectors found in an image, by (image SHA-256, board, "quick" or "robust"):
`DetectionMemo(DETECTION_CACHE_SIZE)`. Only what depends on the image alone is remembered,
never whether the board was predicted to run off it (that depends on the other images of the
calibration), so a calibration with a memo finds exactly what one without finds."""


def calibrate_session(
    reader: SessionReader,
    board: Checkerboard,
    cameras: list[str],
    known: dict[str, KnownIntrinsics] | None = None,
    min_views: int = MIN_VIEWS,
    min_shared_views: int = MIN_SHARED_VIEWS,
    detections: DetectionMemo | None = None,
    image_checks: ImageCheckMemo | None = None,
) -> CameraCalibration:
    """Calibrate every camera of a session from all its checkerboard images.

    Every completed step with camera images ("pose/<nnnn>" and "refmic") is used: each is a
    board view that constrains the intrinsics. With a memo, the detections are remembered by
    the image file's SHA-256 (session files never change once written), so that a long-running
    process (the calibration worker, whose live jobs see the same images again with a few more
    poses each time) decodes and searches each image once. A remembered image is not read
    again, so the memo's owner answers for its files (the worker verified its copies when it
    fetched them); without a memo every image is read, and checked against the journal.

    Args:
        reader: the session.
        board: its checkerboard (`Checkerboard.of_rig`).
        cameras: camera names, camera 0 first.
        known: intrinsics known from elsewhere, by camera name (see `calibrate_detections`).
        detections: the memo of detections to use and fill (None: remember nothing).
        image_checks: the memo of the image checks' measures, likewise.

    Raises:
        CameraCalibrationError: camera 0 has too few views with a board.
    """
    files = {(camera, step): record.files[f"{camera}.png"]
             for step, record in sorted(reader.steps().items())
             for camera in cameras if f"{camera}.png" in record.files}

    def read(key: tuple[str, str]) -> np.ndarray:
        return reader.read_image(key[1], f"{key[0]}.png")

    hashes = {key: file.sha256 for key, file in files.items()}
    found = _detect_all(list(files), read, hashes, detections, cameras, board, known,
                        min_views, min_shared_views)
    flat = calibrate_detections(found, cameras, board, min_views, min_shared_views, known,
                                fit_bow=False)
    verdict = check_images([ViewImage(c, s, corners) for (c, s), (corners, _) in found.items()],
                           read, board, hashes, image_checks)
    kept = {key: d for key, d in found.items() if key not in verdict.left_out}
    if verdict.left_out:
        try:
            flat = calibrate_detections(kept, cameras, board, min_views, min_shared_views,
                                        known, fit_bow=False)
        except CameraCalibrationError as exc:
            mistakes = "; ".join(f.evidence for f in verdict.findings if f.action == "left out")
            raise CameraCalibrationError(f"{exc} (views left out: {mistakes})") from exc
    cams = _with_bow(flat, kept, cameras, min_views, min_shared_views, known)
    left_out = [MissedImage(c, s, f"left out: {reason}")
                for (c, s), reason in verdict.left_out.items()]
    return replace(cams, missed=[*cams.missed, *left_out], findings=verdict.findings)


def _with_bow(
    flat: CameraCalibration, detections: dict[tuple[str, str], Detection], cameras: list[str],
    min_views: int, min_shared_views: int, known: dict[str, KnownIntrinsics] | None,
) -> CameraCalibration:
    """The calibration `flat` (of `detections`, with the flat board) with the board's bow
    estimated, and where it is significant the cameras calibrated again with the sagged
    corners, each started from its flat fit (calibrateCamera needs a start for corners out of
    a plane). Why again: the flat board's misfit of a bowed one would stay in the residuals,
    taken for corner noise (1.8-2.9 times the true one for the realistic lab's 0.5 mm plate
    bow), and in the focal length (2.5-4 px of 1000)."""
    bow = _bow(flat)
    if bow is None or not bow.significant:
        return replace(flat, bow=bow)
    bowed = _calibrate(detections, cameras, flat.board, board_points(flat.board, bow),
                       min_views, min_shared_views, known or {}, flat.intrinsics)
    return replace(bowed, bow=bow)


def _bow(cams: CameraCalibration) -> BoardBow | None:
    """The board's sag from the views of every camera with `MIN_VIEWS` of them."""
    views = [CameraViews(intr.K, intr.dist, (intr.width, intr.height),
                         [v.corners_px for (c, _), v in cams.views.items() if c == name],
                         intr.noise.sigma_px)
             for name, intr in cams.intrinsics.items()]
    usable = [v for v in views if len(v.corners_px) >= MIN_VIEWS]
    if not usable:
        return None
    with _reproducible():
        return estimate_bow(cams.board, usable)


ROUGH_STEPS = 24
"""Steps whose board views give `_runs_off_the_image` its rough calibration (a fraction of a
second; a few pixels are all it needs)."""
CUT_MARGIN_PX = 10.0
"""How far outside the image a predicted inner corner must lie for the board to count as cut
by the image's edge. It was 40 px when one prediction on the realistic lab's 140 poses came
out 24 px off: about one square, the size of the error of a grid detected one column off,
which the ring check (corners.py `_ring_is_printed`) has refused since. Against the truth the
predictions are now within 0.8 px on that session and within 0.7 px on the five 30-pose
ones; the robust detector finds no board cut by the edge (its 13 failures there are 12 px or
more outside, or 6 px inside at a grazing angle) and every board 8 px or more inside. At
10 px it skips 47 of 59 unsure images there, against 35 at 40 px (time of the camera stage
saved), and finds the same views."""


def _runs_off_the_image(
    unsure: list[tuple[str, str]], found: dict[tuple[str, str], Detection],
    cameras: list[str], board: Checkerboard, known: dict[str, KnownIntrinsics] | None,
    min_views: int, min_shared_views: int,
) -> set[tuple[str, str]]:
    """The unsure images (camera, step) whose board, where another camera saw it at the same
    step, runs off the image by more than `CUT_MARGIN_PX`: no detector can find it whole, and
    the robust one would spend 0.1-0.4 s failing (a tenth of the images of a 140-pose
    session of the realistic lab). Predicted from a rough calibration of the cameras on
    `ROUGH_STEPS` steps; an image that cannot be predicted (its camera or no other camera
    calibrated, no other camera's view of the step) is not in the set."""
    seen = {key: corners for key, (corners, _) in found.items() if corners is not None}
    steps = sorted({step for _, step in seen})
    sample = set(steps[::max(1, -(-len(steps) // ROUGH_STEPS))])
    try:
        rough = calibrate_detections({k: d for k, d in found.items() if k[1] in sample},
                                     cameras, board, min_views, min_shared_views, known,
                                     fit_bow=False)
    except (CameraCalibrationError, cv2.error):  # too few or degenerate views: no prediction
        return set()
    obj = board.object_points()
    cut = set()
    for camera, step in unsure:
        others = [c for c in rough.intrinsics if c != camera and (c, step) in seen]
        if camera not in rough.intrinsics or not others:
            continue
        other = rough.intrinsics[others[0]]
        ok, rvec, tvec = cv2.solvePnP(obj, seen[(others[0], step)].reshape(-1, 1, 2),
                                      other.K, other.dist)
        if not ok:
            continue
        to_other = rough.cam_from_cam0[others[0]].cam0_to_cam
        rig_to_cam = rough.cam_from_cam0[camera].cam0_to_cam.compose(
            to_other.inverse_compose(RigidTransform.from_rotvec(rvec.ravel(), tvec.ravel())))
        in_cam = rig_to_cam.apply(obj)
        mine = rough.intrinsics[camera]
        px, _ = cv2.projectPoints(in_cam, np.zeros(3), np.zeros(3), mine.K, mine.dist)
        px = px.reshape(-1, 2)
        outside = ((px < -CUT_MARGIN_PX)
                   | (px > np.array([mine.width, mine.height]) - 1 + CUT_MARGIN_PX))
        if np.any(in_cam[:, 2] <= 0) or outside.any():
            cut.add((camera, step))
    return cut


def calibrate_images(
    images: dict[tuple[str, str], np.ndarray],
    cameras: list[str],
    board: Checkerboard,
    min_views: int = MIN_VIEWS,
    min_shared_views: int = MIN_SHARED_VIEWS,
    known: dict[str, KnownIntrinsics] | None = None,
) -> CameraCalibration:
    """Calibrate cameras from images keyed by (camera, step) (see `calibrate_detections`)."""
    found = _detect_all(list(images), images.__getitem__, {}, None, cameras, board, known,
                        min_views, min_shared_views)
    return calibrate_detections(found, cameras, board, min_views, min_shared_views, known)


def _detect_all(
    keys: list[tuple[str, str]], read: Callable[[tuple[str, str]], np.ndarray],
    hashes: dict[tuple[str, str], str], memo: DetectionMemo | None, cameras: list[str],
    board: Checkerboard, known: dict[str, KnownIntrinsics] | None, min_views: int,
    min_shared_views: int,
) -> dict[tuple[str, str], Detection]:
    """The detections of the images `keys` (camera, step), each read by `read`: the quick
    detectors on every image, then the robust one on those it was unsure of, except where
    the board runs off the image (`_runs_off_the_image`, predicted from the quick detectors'
    finds of these images alone). With a `memo`, each detector's answer for an image is
    remembered by the image's SHA-256 (`hashes`) and not searched again.

    PNG decoding and OpenCV's search release the interpreter lock: one image per core."""

    def remembered(key: tuple[str, str], detector: str,
                   search: Callable[[np.ndarray, Checkerboard], np.ndarray | None | Unsure]
                   ) -> QuickFind:
        entry = None if memo is None else (hashes[key], board, detector)
        if memo is not None and entry is not None and (answer := memo.get(entry)) is not None:
            return answer
        image = read(key)
        answer = (search(image, board), image.shape[1::-1])
        if memo is not None and entry is not None:
            memo.put(entry, answer)
        return answer

    def robustly(key: tuple[str, str]) -> Detection:
        corners, size = remembered(key, "robust", detect_corners_robustly)
        assert not isinstance(corners, Unsure)  # the robust detector is always sure
        return corners, size

    detected: dict[tuple[str, str], Detection] = {}
    unsure: dict[tuple[str, str], tuple[int, int]] = {}
    # one BLAS thread: the images' threads already fill the cores (the corner fit's small
    # batched solves gain nothing from more)
    with single_threaded_blas(), ThreadPoolExecutor(default_workers()) as pool:
        quick = pool.map(lambda key: remembered(key, "quick", detect_corners_quickly), keys)
        for key, (corners, size) in zip(keys, quick, strict=True):
            if isinstance(corners, Unsure):
                unsure[key] = size
            else:
                detected[key] = (corners, size)
        cut = _runs_off_the_image(list(unsure), dict(detected), cameras, board, known,
                                  min_views, min_shared_views) if unsure else set()
        robust = [key for key in unsure if key not in cut]
        detected |= dict(zip(robust, pool.map(robustly, robust), strict=True))
    return detected | {key: (None, unsure[key]) for key in cut}


def calibrate_detections(
    detections: dict[tuple[str, str], Detection],
    cameras: list[str],
    board: Checkerboard,
    min_views: int = MIN_VIEWS,
    min_shared_views: int = MIN_SHARED_VIEWS,
    known: dict[str, KnownIntrinsics] | None = None,
    fit_bow: bool = True,
) -> CameraCalibration:
    """Calibrate cameras from the corners found in their images, keyed by (camera, step), and
    the board's bow (`_with_bow`).

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
        fit_bow: False: the board taken as flat, its bow not estimated (`bow` None).

    Raises:
        CameraCalibrationError: camera 0 has fewer than `min_views` views with a board.
    """
    flat = _calibrate(detections, cameras, board, board.object_points(), min_views,
                      min_shared_views, known or {}, {})
    if not fit_bow:
        return flat
    return _with_bow(flat, detections, cameras, min_views, min_shared_views, known)


def _calibrate(
    detections: dict[tuple[str, str], Detection], cameras: list[str], board: Checkerboard,
    points: np.ndarray, min_views: int, min_shared_views: int,
    known: dict[str, KnownIntrinsics], start: dict[str, CameraIntrinsics],
) -> CameraCalibration:
    """`calibrate_detections` with the board's inner corners at `points` (n_corners, 3) in the
    rig frame, metres, each camera in `start` started from its intrinsics there."""
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
        intrinsics[camera], camera_views = _calibrate_camera(
            camera, own, size, points, known.get(camera), min_views, start.get(camera))
        views.update({(camera, v.step): v for v in camera_views})
    extrinsics = _link_cameras(intrinsics, views, points, min_shared_views)
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
    camera: str, corners: dict[str, np.ndarray], size: tuple[int, int], points: np.ndarray,
    known: KnownIntrinsics | None, min_views: int, start: CameraIntrinsics | None,
) -> tuple[CameraIntrinsics, list[BoardView]]:
    """calibrateCamera on one camera's views (or its known intrinsics) of the board's corners
    at `points` (rig frame, metres), started from `start` (or the known intrinsics, or
    OpenCV's own start: flat boards only), then the covariances and errors of the fit."""
    steps = sorted(corners)
    obj = points.astype(np.float32)
    image_points = [corners[s].astype(np.float32).reshape(-1, 1, 2) for s in steps]
    if known is not None and (known.use == "fixed" or len(steps) < min_views):
        K, dist = np.array(known.camera_matrix), np.array(known.distortion)
        intrinsics_cov = (np.diag(np.square(known.std)) if known.std is not None
                          else np.zeros((9, 9)))
        fits = _fits_with(K, dist, corners, steps, points)
        noise = _corner_noise(fits, None)
    else:
        K0, d0 = None, None
        if start is not None:
            K0, d0 = start.K.copy(), start.dist.copy()
        elif known is not None:
            K0, d0 = np.array(known.camera_matrix), np.array(known.distortion)
        flags = cv2.CALIB_USE_INTRINSIC_GUESS if K0 is not None else 0
        with _reproducible():
            _, K, dist, rvecs, tvecs = cv2.calibrateCamera(
                [obj] * len(steps), image_points, size, K0, d0, flags=flags,
                criteria=_CALIB_CRITERIA
            )
        dist = dist.ravel()[:5]
        fits = [
            _view_fit(corners[s], r.ravel(), t.ravel(), K, dist, points)
            for s, r, t in zip(steps, rvecs, tvecs, strict=True)
        ]
        noise = _corner_noise(fits, _intrinsics_information(fits, np.ones(len(fits))))
        intrinsics_cov = np.linalg.inv(
            _intrinsics_information(fits, noise.view_sigma_px**2))
        if known is not None:
            K, dist, intrinsics_cov = _combine_with_prior(K, dist, intrinsics_cov, known)
            fits = _fits_with(K, dist, corners, steps, points)
    pose_covs = _pose_covariances(fits, noise.view_sigma_px**2, intrinsics_cov)
    views = [
        BoardView(camera, s, corners[s], Pose(f.rig_to_cam, cov), f.rms_px, float(sigma))
        for s, f, cov, sigma in zip(steps, fits, pose_covs, noise.view_sigma_px, strict=True)
    ]
    rms = float(np.sqrt(np.mean([f.rms_px**2 for f in fits])))
    intr = CameraIntrinsics(camera, size[0], size[1], K, dist, intrinsics_cov, rms, len(steps),
                            noise)
    return intr, views


def partial_view(camera: str, step: str, corners_px: np.ndarray, intr: CameraIntrinsics,
                 points: np.ndarray, start: RigidTransform) -> BoardView | None:
    """The board view of an image where only some corners were found (`corners_px`,
    (n_corners, 2), NaN where not): its pose fitted to those corners with the camera's
    intrinsics `intr` (solvePnP from `start`, the pose in that camera's frame), its covariance
    as a whole view's (the camera's corner noise, the intrinsics' uncertainty included).
    `points` are the board's corners in the rig frame, metres. None where no pose fits: the
    view is then not used (that is no reason to refuse the session)."""
    have = np.isfinite(corners_px).all(axis=1)
    ok, rvec, tvec = cv2.solvePnP(points[have], corners_px[have].reshape(-1, 1, 2), intr.K,
                                  intr.dist, start.rotvec.reshape(3, 1).copy(),
                                  start.t.reshape(3, 1).copy(), useExtrinsicGuess=True,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        return None
    fit = _view_fit(corners_px[have], rvec.ravel(), tvec.ravel(), intr.K, intr.dist,
                    points[have])
    variance = intr.noise.sigma_px**2
    cov = _pose_covariances([fit], np.array([variance]), intr.cov)[0]
    return BoardView(camera, step, corners_px, Pose(fit.rig_to_cam, cov), fit.rms_px,
                     intr.noise.sigma_px)


def _corner_noise(fits: list[_ViewFit], information: np.ndarray | None) -> CornerNoise:
    """The camera's corner noise (calibration.camera.corner_noise) from its views' residuals, each
    view having absorbed its pose's 6 parameters and, where the intrinsics were fitted (their
    information at unit noise given), its share tr(S^-1 S_i) of their 9: S_i is the view's
    term of the Schur complement S (`_intrinsics_information`), so the shares sum to 9."""
    absorbed = np.full(len(fits), 6.0)
    if information is not None:
        S_inv = np.linalg.inv(information)
        absorbed += [np.trace(S_inv @ _schur_term(f, 1.0)) for f in fits]
    return estimate_corner_noise(np.array([f.sum_sq_px2 for f in fits]),
                                 np.array([len(f.J_pose) // 2 for f in fits]), absorbed)


def _fits_with(K: np.ndarray, dist: np.ndarray, corners: dict[str, np.ndarray],
               steps: list[str], points: np.ndarray) -> list[_ViewFit]:
    """Every view's board pose fitted with the given intrinsics (solvePnP) to the corners at
    `points` (rig frame), and its fit."""
    fits = []
    for s in steps:
        ok, rvec, tvec = cv2.solvePnP(points, corners[s].reshape(-1, 1, 2), K, dist,
                                      flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok:
            raise CameraCalibrationError(f"no board pose fits the corners of {s} with the "
                                         "known intrinsics; check the intrinsics file")
        fits.append(_view_fit(corners[s], rvec.ravel(), tvec.ravel(), K, dist, points))
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
        rig_to_cam: the pose, made from the fitted rotation vector.
        J_pose: (2 n, 6) derivatives of the pixel coordinates by (rvec, tvec).
        J_intr: (2 n, 9) derivatives by (fx, fy, cx, cy, k1, k2, p1, p2, k3).
        sum_sq_px2: sum of the squared residuals of the view's corners, px^2.
        rms_px: RMS reprojection error per corner, pixels.
    """

    rig_to_cam: RigidTransform
    J_pose: np.ndarray
    J_intr: np.ndarray
    sum_sq_px2: float
    rms_px: float


def _view_fit(
    corners: np.ndarray,
    rvec: np.ndarray,
    tvec: np.ndarray,
    K: np.ndarray,
    dist: np.ndarray,
    points: np.ndarray,
) -> _ViewFit:
    """Reprojection residuals and Jacobians of one view of the corners at `points` (rig frame,
    metres; cv2.projectPoints)."""
    projected, jac = cv2.projectPoints(points, rvec, tvec, K, dist)
    residual = corners - projected.reshape(-1, 2)
    sq = float(np.sum(residual**2))
    return _ViewFit(
        rig_to_cam=RigidTransform.from_rotvec(rvec, tvec),
        J_pose=jac[:, :6],
        J_intr=jac[:, 6:15],
        sum_sq_px2=sq,
        rms_px=float(np.sqrt(sq / len(residual))),
    )


def _schur_term(f: _ViewFit, variance: float) -> np.ndarray:
    """A view's term (9, 9) of the intrinsics' information with the poses marginalized out
    (`_intrinsics_information`), at the given noise variance per coordinate (px^2)."""
    W = f.J_intr.T @ f.J_pose
    return (f.J_intr.T @ f.J_intr - W @ np.linalg.inv(f.J_pose.T @ f.J_pose) @ W.T) / variance


def _intrinsics_information(fits: list[_ViewFit], variances: np.ndarray) -> np.ndarray:
    """Information matrix (9, 9) of the intrinsics in the joint fit of all views, the poses
    marginalized out.

    The information matrix of the joint fit, each view weighted by its corner noise's
    variance s_i^2 (px^2 per coordinate: a blurred image counts less), is [[U, W], [W^T, V]]
    with V block-diagonal: V_i = J_i^T J_i / s_i^2, W_i = C_i^T J_i / s_i^2,
    U = sum C_i^T C_i / s_i^2 (J: pose Jacobian, C: intrinsics Jacobian). The intrinsics'
    information is the Schur complement S = U - sum W_i V_i^-1 W_i^T (its inverse their
    covariance).
    """
    return sum((_schur_term(f, v) for f, v in zip(fits, variances, strict=True)),
               np.zeros((9, 9)))


def _pose_covariances(fits: list[_ViewFit], variances: np.ndarray,
                      intrinsics_cov: np.ndarray) -> list[np.ndarray]:
    """Each pose's marginal covariance (6, 6): V_i^-1 + V_i^-1 W_i^T C W_i V_i^-1, its own
    noise plus the intrinsics' uncertainty C (notation of `_intrinsics_information`; the views'
    corner noise variances s_i^2, px^2).

    Why the second term: a focal-length error scales every pose's depth; left out, the
    covariance claims depths several times better than they are. (The intrinsics' errors also
    correlate the poses with each other; those cross terms are not returned.)
    """
    covs = []
    for f, variance in zip(fits, variances, strict=True):
        V_inv = np.linalg.inv(f.J_pose.T @ f.J_pose / variance)
        W = f.J_intr.T @ f.J_pose / variance
        covs.append(V_inv + V_inv @ W.T @ intrinsics_cov @ W @ V_inv)
    return covs


# ---------------------------------------------------------------------------------------------
# Camera-to-camera transforms


def _link_cameras(
    intrinsics: dict[str, CameraIntrinsics],
    views: dict[tuple[str, str], BoardView],
    points: np.ndarray,
    min_shared_views: int,
) -> dict[str, Extrinsics]:
    """Each camera's transform from camera 0, breadth-first through shared views.

    A camera that shares no views with camera 0 is still linked through a camera that does
    (cameras around a sphere may each overlap only with their neighbours).
    """
    cameras = list(intrinsics)
    reference = cameras[0]
    linked = {reference: Extrinsics(RigidTransform.identity(), 0.0, 0, reference)}
    queue = deque([reference])
    while queue:
        known = queue.popleft()
        for camera in cameras:
            if camera in linked:
                continue
            shared = _shared_steps(views, known, camera)
            if len(shared) < min_shared_views:
                continue
            known_to_cam, rms = _stereo(intrinsics[known], intrinsics[camera], views, shared,
                                        points)
            cam0_to_cam = known_to_cam.compose(linked[known].cam0_to_cam)
            linked[camera] = Extrinsics(cam0_to_cam, rms, len(shared), known)
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
    points: np.ndarray,
) -> tuple[RigidTransform, float]:
    """The transform x_second = R x_first + t and its RMS error (pixels) from
    stereoCalibrate, intrinsics fixed.

    Fitting the transform to the corners of both images of every shared view weighs each
    view by how well it constrains the transform, unlike averaging per-view pose differences.
    The board's corners are at `points` (rig frame, metres).
    """
    obj = points.astype(np.float32)
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
    return RigidTransform(R, t.ravel()), float(rms)
