"""The optical-acoustic bundle adjustment: cameras and array fitted together (DESIGN.md, "The
final fit is an optical-acoustic bundle adjustment").

Why: a camera calibrated first and then frozen carries its focal-length error (a few 0.01 %
with 20-30 views) into the depth of every speaker, which c cannot absorb, and so into a common
depth offset of the whole array. The times of flight are precise to a fraction of a
microsecond; fitted together with the corner pixels they correct the camera.

Model (frames of `calibration.camera.camera_calibration`; x_cam = R(rvec) x + t everywhere):

- corner j of the board in view (camera i, pose k):
  pixel = project_i(R_i (R_k (s B_j) + t_k) + t_i) with camera i's intrinsics (fx, fy, cx, cy)
  and OpenCV's 5 distortion coefficients, the board pose k (rig -> camera 0), camera i's
  transform from camera 0 (identity for camera 0) and the print's scale s (1: as stated);
- time of flight from speaker s of pose k to microphone m (paper eq. 15, extended):
  tau = (|v| - b (1 - cos theta) cos theta - d_ref) / c_k + d_ref / c_tof + delta_b(m) + e_m,
  v = X_m - (R_k (P_s + D_s) + t_k), with D_s the speaker's offset on the rig from its stated
  position P_s (build tolerance and acoustic centre), theta the angle between the rig's normal
  R_k z and v, b how far the acoustic centre moves forward off the speaker's axis (a driver's
  acoustic centre depends on frequency, and off axis its high frequencies roll off: the
  centre a correlation sees moves with the angle, by tens of micrometres at 50 degrees), c_k
  the speed of sound during pose k, delta_b the board latency, e_m the microphone's own
  delay (and, for a speaker measured on another speaker's reference recording, g_s: its
  emission delay relative to that speaker's, free), and d_ref the reference microphone's distance from the diaphragm during the
  reference recording (measured delays are relative to that recording; the TOFs handed in
  had d_ref / c_tof added, so the model takes it out again at the fitted c);
- time of flight from the same source to the reference microphone on its stand (position an
  unknown; no latency or own delay: its board is the latency gauge and its capsule is the
  reference recording's).

Gauges, fixed explicitly: the frame is camera 0's (it has no extrinsics unknowns); the
latency of the board recording the reference microphone is 0 (the other boards' latencies
are relative to it, as measured). The metric scale is a confound: scaling every length and c
by one factor leaves every observation unchanged. Only the priors break it: the print's
stated scale (print_scale_std), the speakers' stated positions (their tolerance), and a known
speed of sound (a thermometer). The covariance carries what is left of it.

Unknowns: every camera's 9 intrinsics, the other cameras' extrinsics (6 each), every board
pose including the reference-microphone step (6 each), the microphones (3 each), the reference
microphone (3), c (one, or one per pose), the latencies, and with their priors (`BundlePriors`)
the microphones' own delays, the speakers' rig offsets, the off-axis move b, the print
scale and the emission delays g_s of speakers on a lent reference recording. Residuals are whitened: corner pixels by a per-camera sigma (times each view's noise
relative to its camera's, as the camera calibration estimated it:
`BundleProblem.corner_sigma_px`), times of flight by their predicted std times a per-kind
scale; both are estimated from the residual scatter (median absolute deviation) at the start
and again after each pass, the corners' last from residuals standardized by their leverage
(`_corner_sigmas_for_leverage`). The priors are Gaussian pseudo-observations with the stated
standard deviations (never rescaled, never down-weighted).

Solver: Levenberg-Marquardt on the normal equations J^T W J, which are small (about 1,100
unknowns for 140 poses) even when J has 10^5 rows; J is sparse and analytic (OpenCV's
projectPoints derivatives for the pixels, the model's own for the times of flight). The loss
is Huber's, by iteratively reweighted least squares; residuals beyond `outlier_threshold`
sigmas after a pass are outliers, left out of the next pass and reported. The covariance of
the unknowns is the cluster-robust sandwich around the final J^T W J (`_Pass.covariance`):
the residuals' own scatter, with the errors of one pose's speakers at one microphone allowed
to correlate.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy import sparse
from scipy.linalg import cho_factor, cho_solve
from scipy.spatial.transform import Rotation

from kernel.air import NOMINAL_SPEED_OF_SOUND_M_S, SpeedOfSoundPrior
from kernel.rigid import RigidTransform, rotated_point_jacobian, rotation_from_rotvec

from .._blas import single_threaded_blas
from .._cores import default_workers
from ..camera.camera_calibration import CameraCalibration, CameraIntrinsics, Extrinsics, Pose
from .robust import inverse_normal, robust_sigma

FIXED = 0.0
"""A prior standard deviation of 0 fixes the unknown at its prior mean."""

N_INTRINSICS = 9
"""fx, fy, cx, cy, k1, k2, p1, p2, k3 (OpenCV's order, projectPoints' Jacobian columns 6-15)."""
GROUP_TOF = "tof"
GROUP_REFERENCE = "reference tof"


@dataclass(frozen=True)
class BundleOptions:
    """Options of `fit_bundle`.

    Attributes:
        huber_k: Huber's threshold in sigmas: residuals beyond it are down-weighted as k/|r|
            (95 % efficiency at Gaussian noise for k = 1.345; 3 keeps nearly all of it and
            still bounds a gross outlier's pull).
        outlier_threshold: residuals (corners: the 2D error) beyond this many sigmas after
            the first pass are outliers, excluded from the second pass and reported.
        max_iterations: Levenberg-Marquardt iterations per pass.
        tolerance: relative decrease of the cost below which the final pass has converged
            (the cost is a chi-square of about one per row: 1e-8 of 1e5 rows is a step of
            about a hundredth of the unknowns' sigmas, and the last steps shrink
            quadratically).
        pass_tolerance: the same for the passes before it, whose sigmas and outliers change
            after them anyway.
        max_passes: passes at most (see `fit_bundle`).
        sigma_tolerance: relative change of every noise group's sigma below which the noise
            estimate has settled.
    """

    huber_k: float = 3.0
    outlier_threshold: float = 5.0
    max_iterations: int = 50
    tolerance: float = 1e-8
    pass_tolerance: float = 1e-6
    max_passes: int = 10
    sigma_tolerance: float = 0.03


@dataclass(frozen=True)
class BundleProblem:
    """The observations of the joint fit, as plain arrays.

    Attributes:
        board_points_m: (n_corner, 3) checkerboard inner corners in the rig frame (the scale).
        speakers_rig_m: (n_speaker, 3) speaker positions in the rig frame.
        view_camera, view_pose: (n_view,) camera index and pose index of every board view.
        corners_px: (n_view, n_corner, 2) detected corners in rig order, NaN where a view
            lacks a corner (a view recovered in part: calibration.camera.recovered_views).
        pose_of_source, speaker_of_source: (n_src,) pose and speaker of every source.
        tof_s, tof_std_s: (n_src, n_mic) array times of flight and their predicted std, NaN
            where missing (an infinite std, no signal, counts as missing).
        reference_tof_s, reference_std_s: (n_src,) times of flight to the reference
            microphone and their predicted std (NaN where missing, as above).
        latency_column: (n_mic,) latency unknown of each microphone (-1: its board is the
            gauge, latency 0).
        n_latency: number of latency unknowns.
        camera_names: camera names, camera 0 first (for the noise groups' names).
        reference_distance_m: (n_src,) the reference microphone's distance from the
            diaphragm in the reference recording of each source's speaker (0: the TOFs are
            already absolute).
        tof_speed_of_sound_m_s: the c at which reference_distance_m / c was added to the
            TOFs handed in (the model replaces it by the fitted c).
        speed_of_sound_of_pose: (n_pose,) index of the c unknown of each board pose (-1: a
            pose without sources); None: one c for the whole session.
        priors: the Gaussian priors of the optional unknowns (`BundlePriors`).
        corner_sigma_px: (n_view,) each view's corner noise as the camera calibration
            estimated it (`view_sigmas`), pixels per coordinate: a view's corners are
            weighted by it relative to its camera's other views (a blurred or distant view
            counts less), each camera's scale estimated again from the joint fit's
            residuals. None: a camera's views alike.
    """

    board_points_m: np.ndarray
    speakers_rig_m: np.ndarray
    view_camera: np.ndarray
    view_pose: np.ndarray
    corners_px: np.ndarray
    pose_of_source: np.ndarray
    speaker_of_source: np.ndarray
    tof_s: np.ndarray
    tof_std_s: np.ndarray
    reference_tof_s: np.ndarray
    reference_std_s: np.ndarray
    latency_column: np.ndarray
    n_latency: int
    camera_names: tuple[str, ...]
    reference_distance_m: np.ndarray | None = None
    tof_speed_of_sound_m_s: float = NOMINAL_SPEED_OF_SOUND_M_S
    speed_of_sound_of_pose: np.ndarray | None = None
    priors: BundlePriors | None = None
    corner_sigma_px: np.ndarray | None = None

    @property
    def n_camera(self) -> int:
        return len(self.camera_names)

    @property
    def n_speed_of_sound(self) -> int:
        """Number of c unknowns."""
        c_pose = self.speed_of_sound_of_pose
        return 1 if c_pose is None else int(np.max(c_pose, initial=-1)) + 1


@dataclass(frozen=True)
class BundlePriors:
    """Gaussian priors of the unknowns that the data alone cannot pin, from what the rig's
    description states (a standard deviation of 0 = FIXED at the mean: not an unknown).

    Attributes:
        speaker_offset_mean_m: (n_speaker, 3) expected offset of each speaker from its stated
            rig position (e.g. an expected acoustic-centre offset along the rig's Z).
        speaker_offset_std_m: (n_speaker, 3) its standard deviation per axis (in-plane: the
            build tolerance; along Z: the acoustic centre's uncertainty).
        print_scale_std: relative standard deviation of the printed pattern's scale.
        off_axis_std_m: standard deviation of b, the acoustic centre's move off axis
            (prior mean 0).
        mic_delay_std_s: standard deviation of each microphone's own delay (capsule and
            channel group delay) about the mean of its board.
        speaker_delay_std_s: (n_speaker,) standard deviation of each speaker's emission delay
            g_s (prior mean 0): FIXED for a speaker correlated with its own reference
            recording, a wide one for a speaker measured on another's (whose driver and cable
            delay the lent recording does not hold); None: every one FIXED.
        speed_of_sound: (c, std) a known speed of sound (a thermometer), m/s, as a prior on
            the session's mean c; None: unknown.
        speed_of_sound_step_m_s: standard deviation of the change of c from one pose to the
            next, when c is fitted per pose (the air drifting).
        intrinsics_mean, intrinsics_std: (n_camera, 9) intrinsics known from elsewhere and
            their standard deviations (0: FIXED; NaN: nothing known, fitted freely); None:
            every camera fitted freely.
    """

    speaker_offset_mean_m: np.ndarray
    speaker_offset_std_m: np.ndarray
    print_scale_std: float = FIXED
    off_axis_std_m: float = FIXED
    mic_delay_std_s: float = FIXED
    speaker_delay_std_s: np.ndarray | None = None
    speed_of_sound: SpeedOfSoundPrior | None = None
    speed_of_sound_step_m_s: float = 0.01
    intrinsics_mean: np.ndarray | None = None
    intrinsics_std: np.ndarray | None = None

    @classmethod
    def none(cls, n_speaker: int) -> BundlePriors:
        """Every optional unknown fixed: the model of the ideal world."""
        return cls(np.zeros((n_speaker, 3)), np.zeros((n_speaker, 3)))


@dataclass(frozen=True)
class BundleState:
    """Values of every unknown (the start or the solution).

    Attributes:
        intrinsics: (n_camera, 9) fx, fy, cx, cy (pixels), k1, k2, p1, p2, k3.
        extrinsics: (n_camera - 1, 6) rvec (rad), t (m) of cameras 1.. from camera 0.
        poses: (n_pose, 6) rvec (rad), t (m) of every board pose, rig -> camera 0.
        microphones_m: (n_mic, 3) microphone positions, camera-0 frame.
        reference_m: (3,) the reference microphone's position on its stand.
        speeds_of_sound_m_s: (n_c,) c, one for the session or one per pose with sources.
        latencies_s: (n_latency,) board latencies relative to the gauge board.
        mic_delays_s: (n_mic,) each microphone's own delay (empty: zeros).
        speaker_offsets_m: (n_speaker, 3) each speaker's offset from its stated rig position,
            rig frame (empty: zeros).
        print_scale: the printed pattern's scale relative to the stated one.
        off_axis_m: b, how far the speakers' acoustic centre moves forward off axis (at
            theta: b (1 - cos theta) along the normal).
        speaker_delays_s: (n_speaker,) each speaker's emission delay g_s (empty: zeros).
    """

    intrinsics: np.ndarray
    extrinsics: np.ndarray
    poses: np.ndarray
    microphones_m: np.ndarray
    reference_m: np.ndarray
    speeds_of_sound_m_s: np.ndarray
    latencies_s: np.ndarray
    mic_delays_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    speaker_offsets_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    print_scale: float = 1.0
    off_axis_m: float = 0.0
    speaker_delays_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def speed_of_sound_m_s(self) -> float:
        """The session's mean c."""
        return float(np.mean(self.speeds_of_sound_m_s))

    def completed(self, n_speaker: int) -> BundleState:
        """The state with its optional unknowns filled in (zeros where empty)."""
        delays = np.asarray(self.mic_delays_s, float)
        offsets = np.asarray(self.speaker_offsets_m, float).reshape(-1, 3)
        emission = np.asarray(self.speaker_delays_s, float)
        return replace(
            self,
            speeds_of_sound_m_s=np.atleast_1d(np.asarray(self.speeds_of_sound_m_s, float)),
            mic_delays_s=delays if delays.size else np.zeros(len(self.microphones_m)),
            speaker_offsets_m=offsets if offsets.size else np.zeros((n_speaker, 3)),
            speaker_delays_s=emission if emission.size else np.zeros(n_speaker),
        )


@dataclass(frozen=True)
class BundleSolution:
    """The joint fit's estimates, their covariance and its diagnostics.

    Attributes:
        state: the estimates.
        std: the same shapes as `state`'s arrays, standard deviations (from the covariance).
        covariance: full covariance of the parameter vector (see `parameter_slices`).
        parameter_slices: name -> slice of the parameter vector ("intrinsics", "extrinsics",
            "poses", "microphones", "reference", "c", "latencies", "mic_delays",
            "speaker_offsets", "print_scale", "off_axis", "speaker_delays"); fixed unknowns
            have zero
            variance.
        sigmas: noise group -> estimated sigma: pixels per coordinate for a camera's corners,
            a factor on the predicted std for the times of flight (estimated per microphone;
            "tof" is their median).
        corner_residuals_px: (n_view, n_corner, 2) detected minus modelled corners, NaN where
            a view lacks the corner.
        tof_residuals_s: (n_src, n_mic) measured minus modelled times of flight, NaN where
            missing.
        reference_residuals_s: (n_src,) the same for the reference microphone.
        corner_outliers: (n_view, n_corner) corners left out as outliers (not those a view
            lacks).
        corner_rms_px: (n_camera,) RMS reprojection error per kept corner of each camera.
        tof_outliers: (n_src, n_mic) times of flight left out as outliers.
        reference_outliers: (n_src,) reference times of flight left out.
        chi2_per_dof: of the final pass (about 1 if the noise model fits).
        iterations: Levenberg-Marquardt iterations of all passes.
        speed_of_sound_of_pose: the problem's (n_pose,) c unknown of each board pose (-1: a
            pose without sources), None with one c for the session.
    """

    state: BundleState
    std: BundleState
    covariance: np.ndarray
    parameter_slices: dict[str, slice]
    sigmas: dict[str, float]
    corner_residuals_px: np.ndarray
    tof_residuals_s: np.ndarray
    reference_residuals_s: np.ndarray
    corner_outliers: np.ndarray
    corner_rms_px: np.ndarray
    tof_outliers: np.ndarray
    reference_outliers: np.ndarray
    chi2_per_dof: float
    iterations: int
    speed_of_sound_of_pose: np.ndarray | None = None

    def speed_of_sound_at(self, pose: int) -> float:
        """The fitted c (m/s) during board pose `pose`: its own where c was fitted per pose,
        the session's otherwise (and for a pose without sources)."""
        column = (-1 if self.speed_of_sound_of_pose is None
                  else int(self.speed_of_sound_of_pose[pose]))
        if column < 0:
            return self.state.speed_of_sound_m_s
        return float(self.state.speeds_of_sound_m_s[column])

    @property
    def speed_of_sound_std_m_s(self) -> float:
        """Standard deviation of the session's mean c."""
        sl = self.parameter_slices["c"]
        block = self.covariance[sl, sl]
        return float(np.sqrt(max(float(block.sum()), 0.0)) / block.shape[0])

    def marginal(self, name: str, index: int, width: int) -> np.ndarray:
        """(width, width) covariance of block `index` of the named unknowns (e.g. the 6 pose
        parameters of pose 3: marginal("poses", 3, 6))."""
        start = self.parameter_slices[name].start + index * width
        return self.covariance[start:start + width, start:start + width]


# ---------------------------------------------------------------------------------------------
# The parameter vector


@dataclass(frozen=True)
class _Layout:
    """Where each kind of unknown sits in the parameter vector."""

    slices: dict[str, slice]
    shapes: dict[str, tuple[int, ...]]

    @classmethod
    def of(cls, state: BundleState) -> _Layout:
        """The layout of a completed state (`BundleState.completed`)."""
        shapes = {
            "intrinsics": state.intrinsics.shape, "extrinsics": state.extrinsics.shape,
            "poses": state.poses.shape, "microphones": state.microphones_m.shape,
            "reference": (3,), "c": state.speeds_of_sound_m_s.shape,
            "latencies": state.latencies_s.shape, "mic_delays": state.mic_delays_s.shape,
            "speaker_offsets": state.speaker_offsets_m.shape, "print_scale": (1,),
            "off_axis": (1,), "speaker_delays": state.speaker_delays_s.shape,
        }  # fmt: skip
        slices, start = {}, 0
        for name, shape in shapes.items():
            size = int(np.prod(shape))
            slices[name] = slice(start, start + size)
            start += size
        return cls(slices, shapes)

    @property
    def size(self) -> int:
        return self.slices["speaker_delays"].stop

    def pack(self, s: BundleState) -> np.ndarray:
        return np.concatenate([s.intrinsics.ravel(), s.extrinsics.ravel(), s.poses.ravel(),
                               s.microphones_m.ravel(), s.reference_m, s.speeds_of_sound_m_s,
                               s.latencies_s, s.mic_delays_s, s.speaker_offsets_m.ravel(),
                               [s.print_scale], [s.off_axis_m], s.speaker_delays_s])  # fmt: skip

    def unpack(self, x: np.ndarray) -> BundleState:
        part = {n: x[sl].reshape(self.shapes[n]) for n, sl in self.slices.items()}
        return BundleState(part["intrinsics"], part["extrinsics"], part["poses"],
                           part["microphones"], part["reference"], part["c"],
                           part["latencies"], part["mic_delays"], part["speaker_offsets"],
                           float(part["print_scale"][0]),
                           float(part["off_axis"][0]), part["speaker_delays"])  # fmt: skip

    def columns(self, name: str, index: np.ndarray, width: int) -> np.ndarray:
        """(n, width) parameter columns of blocks `index` of the named unknowns."""
        return self.slices[name].start + width * np.asarray(index)[:, None] + np.arange(width)


# ---------------------------------------------------------------------------------------------
# Residuals and Jacobian


@dataclass
class _Triplets:
    """COO entries of a sparse Jacobian, collected block by block."""

    rows: list[np.ndarray] = field(default_factory=list)
    cols: list[np.ndarray] = field(default_factory=list)
    vals: list[np.ndarray] = field(default_factory=list)

    def add(self, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> None:
        """rows (n,), cols (n, w) and vals (n, w): row r gets vals[r] in columns cols[r]."""
        self.rows.append(np.repeat(rows, cols.shape[1]))
        self.cols.append(cols.ravel())
        self.vals.append(vals.ravel())

    def matrix(self, n_rows: int, n_cols: int, pattern: _Pattern | None = None
               ) -> tuple[sparse.csr_matrix, _Pattern]:
        """The CSR matrix of the entries (duplicates summed), and its pattern; `pattern`, a
        pattern of earlier entries, is reused when the entries sit where they sat then."""
        rows, cols = np.concatenate(self.rows), np.concatenate(self.cols)
        if pattern is None or not pattern.fits(rows, cols, n_rows, n_cols):
            pattern = _Pattern.of(rows, cols, n_rows, n_cols)
        return pattern.matrix(np.concatenate(self.vals)), pattern


@dataclass(frozen=True)
class _Pattern:
    """Where COO entries go in a CSR matrix: the Jacobian's entries sit in the same places at
    every iteration, so the sorting that SciPy's COO-to-CSR conversion repeats (a third of
    building the matrix at 140 poses) is done once.

    Attributes:
        rows, cols: (n,) the entries' positions, in the order they were added.
        slot: (n,) each entry's index into the CSR data (entries at one position share it).
        indices, indptr: the CSR structure; shape: (n_rows, n_cols).
    """

    rows: np.ndarray
    cols: np.ndarray
    slot: np.ndarray
    indices: np.ndarray
    indptr: np.ndarray
    shape: tuple[int, int]

    @classmethod
    def of(cls, rows: np.ndarray, cols: np.ndarray, n_rows: int, n_cols: int) -> _Pattern:
        keys, slot = np.unique(rows.astype(np.int64) * n_cols + cols, return_inverse=True)
        indptr = np.searchsorted(keys // n_cols, np.arange(n_rows + 1))
        return cls(rows, cols, slot, (keys % n_cols).astype(np.int32),
                   indptr.astype(np.int32), (n_rows, n_cols))

    def fits(self, rows: np.ndarray, cols: np.ndarray, n_rows: int, n_cols: int) -> bool:
        return (self.shape == (n_rows, n_cols) and np.array_equal(self.rows, rows)
                and np.array_equal(self.cols, cols))

    def matrix(self, vals: np.ndarray) -> sparse.csr_matrix:
        data = np.bincount(self.slot, weights=vals, minlength=self.indices.size)
        return sparse.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


@dataclass(frozen=True)
class _Rows:
    """The residual rows of one noise group: their indices and base sigma (the sigma before
    the group's scale), the size of a residual group (2 for a corner's pixel pair), and the
    family of groups it belongs to (every microphone's TOFs are one family; a camera's
    corners and the reference TOFs are each their own)."""

    name: str
    index: np.ndarray
    base_sigma: np.ndarray
    width: int
    family: str


def _measured(tof_s: np.ndarray, std_s: np.ndarray) -> np.ndarray:
    """Where a time of flight is data: finite, with a finite positive std. An infinite std
    (no signal: a silent column's, whose Fisher information is 0) says nothing, and as a row it
    would make its group's sigma inf and their ratios NaN."""
    return np.isfinite(tof_s) & np.isfinite(std_s) & (std_s > 0)


def _corner_rows(views: np.ndarray, n_corner: int) -> np.ndarray:
    """Residual rows (u, v of every corner) of the given views, in order."""
    return (2 * n_corner * views[:, None] + np.arange(2 * n_corner)).ravel()


def _relative_sigmas(view_sigma_px: np.ndarray | None, views: np.ndarray,
                     n_corner: int) -> np.ndarray:
    """The base sigmas of one camera's corner rows (`_corner_rows` of `views`): each view's
    corner noise over the median of the camera's views' (1 for a view of the camera's
    pooled noise: the group's scale is then the camera's corner noise in pixels), or 1 for
    every view without estimates."""
    if view_sigma_px is None or views.size == 0:
        return np.ones(2 * n_corner * views.size)
    sigma = view_sigma_px[views]
    return np.repeat(sigma / np.median(sigma), 2 * n_corner)


class _Model:
    """Unwhitened residuals (model - measurement) and their Jacobian at a state."""

    def __init__(self, problem: BundleProblem, layout: _Layout) -> None:
        self.p = problem
        self.layout = layout
        n_view, n_corner = problem.corners_px.shape[:2]
        self.n_corner_rows = 2 * n_view * n_corner
        self.tof_valid = _measured(problem.tof_s, problem.tof_std_s)
        self.src, self.mic = np.nonzero(self.tof_valid)
        self.ref_valid = np.flatnonzero(_measured(problem.reference_tof_s,
                                                  problem.reference_std_s))
        self.n_rows = self.n_corner_rows + self.src.size + self.ref_valid.size
        # rows with a measurement: every TOF row (the missing ones have none), and the
        # corners a view has (a view recovered in part lacks some)
        self.measured = np.ones(self.n_rows, dtype=bool)
        self.measured[:self.n_corner_rows] = np.isfinite(problem.corners_px).ravel()
        self.groups = self._groups()
        self._pattern: _Pattern | None = None  # the Jacobian's, found at its first evaluation

    def _groups(self) -> list[_Rows]:
        """Rows of every noise group: each camera's corners, array TOFs, reference TOFs."""
        p, groups = self.p, []
        n_corner = p.corners_px.shape[1]
        for i, name in enumerate(p.camera_names):
            views = np.flatnonzero(p.view_camera == i)
            rows = _corner_rows(views, n_corner)
            groups.append(_Rows(name, rows, _relative_sigmas(p.corner_sigma_px, views, n_corner),
                                2, name))
        start = self.n_corner_rows
        base = p.tof_std_s[self.tof_valid]
        for m in range(p.tof_s.shape[1]):  # each microphone its own noise level
            rows = np.flatnonzero(self.mic == m)
            groups.append(_Rows(f"{GROUP_TOF} {m}", start + rows, base[rows], 1, GROUP_TOF))
        start += self.src.size
        groups.append(_Rows(GROUP_REFERENCE, start + np.arange(self.ref_valid.size),
                            p.reference_std_s[self.ref_valid], 1, GROUP_REFERENCE))
        return groups

    def clusters(self) -> np.ndarray:
        """(n_rows,) the error cluster of every residual row, for the covariance's sandwich:
        a corner's pixel pair; the times of flight from one pose's speakers to one
        microphone (pose-major); the reference microphone's from one pose's speakers.

        Why the pose's speakers together: their errors that the model leaves out (the room's
        early reflections, the speakers' directivity, a capsule's response to the direction
        they come from) are nearly the same for sources a few centimetres apart on the rig. On
        the realistic lab they share about 7 % of their variance, which independent weights
        would count six times as information about the microphone's distance."""
        p = self.p
        n_pose = p.pose_of_source.max(initial=0) + 1
        corners = np.arange(self.n_corner_rows) // 2
        tofs = corners.size + p.pose_of_source[self.src] * p.tof_s.shape[1] + self.mic
        reference = corners.size + n_pose * p.tof_s.shape[1] + p.pose_of_source[self.ref_valid]
        return np.concatenate([corners, tofs, reference])

    def evaluate(self, x: np.ndarray, jacobian: bool) -> tuple[np.ndarray, sparse.csr_matrix]:
        s = self.layout.unpack(x)
        trip = _Triplets() if jacobian else None
        corners = self._corners(s, trip)
        sources, d_sources = self._sources(s)
        tofs = self._tofs(s, (sources, d_sources, *self._normals(s)), trip)
        residual = np.concatenate([corners, tofs])
        if trip is None:
            return residual, None
        jac, self._pattern = trip.matrix(self.n_rows, self.layout.size, self._pattern)
        return residual, jac

    def _corners(self, s: BundleState, trip: _Triplets | None) -> np.ndarray:
        """Modelled minus detected pixels of every corner, (2 n_view n_corner,), view by view;
        each camera's points are projected in one call of cv2.projectPoints with rvec = tvec = 0,
        whose translation derivatives are then d(pixel)/d(point in the camera frame)."""
        p = self.p
        n_view, n_corner = p.corners_px.shape[:2]
        out = np.empty((n_view, n_corner, 2))
        R_pose = Rotation.from_rotvec(s.poses[:, :3]).as_matrix()
        board = s.print_scale * p.board_points_m
        for i in range(p.n_camera):
            views = np.flatnonzero(p.view_camera == i)
            if views.size == 0:
                continue
            k = p.view_pose[views]
            Y = np.einsum("vab,cb->vca", R_pose[k], board) + s.poses[k, None, 3:]
            if i > 0:
                X = RigidTransform.from_rotvec(s.extrinsics[i - 1, :3],
                                               s.extrinsics[i - 1, 3:]).apply(Y)
            else:
                X = Y
            K = np.array([[s.intrinsics[i, 0], 0, s.intrinsics[i, 2]],
                          [0, s.intrinsics[i, 1], s.intrinsics[i, 3]], [0, 0, 1.0]])
            projected, jac = cv2.projectPoints(X.reshape(-1, 3), np.zeros(3), np.zeros(3), K,
                                               s.intrinsics[i, 4:])
            out[views] = projected.reshape(len(views), n_corner, 2) - p.corners_px[views]
            if trip is not None:
                self._corner_jacobian(trip, i, views, k, s, Y, jac, R_pose)
        # a corner a view lacks: residual 0 (never kept, so it weighs nothing)
        return np.where(self.measured[:self.n_corner_rows], out.ravel(), 0.0)

    def _corner_jacobian(self, trip: _Triplets, i: int, views: np.ndarray, k: np.ndarray,
                         s: BundleState, Y: np.ndarray, jac: np.ndarray,
                         R_pose: np.ndarray) -> None:
        """Jacobian rows of camera i's corners: intrinsics, pose k, camera i's extrinsics, the
        print scale."""
        n_corner = self.p.corners_px.shape[1]
        rows = _corner_rows(views, n_corner)
        lay = self.layout
        trip.add(rows, lay.columns("intrinsics", np.full(rows.size, i), N_INTRINSICS),
                 jac[:, 6:15])
        d_pix_d_X = jac[:, 3:6].reshape(-1, 2, 3)  # per point: d(u, v) / d(x, y, z)
        R_i = (Rotation.from_rotvec(s.extrinsics[i - 1, :3]).as_matrix() if i > 0
               else np.eye(3))
        board = np.broadcast_to(s.print_scale * self.p.board_points_m, Y.shape).reshape(-1, 3)
        pose_of_point = np.repeat(k, n_corner)
        d_Y_d_pose = np.concatenate(
            [rotated_point_jacobian(s.poses[pose_of_point, :3], board),
             np.broadcast_to(np.eye(3), (board.shape[0], 3, 3))], axis=2)
        d_pose = np.einsum("npa,ab,nbw->npw", d_pix_d_X, R_i, d_Y_d_pose).reshape(-1, 6)
        trip.add(rows, lay.columns("poses", np.repeat(pose_of_point, 2), 6), d_pose)
        # d Y / d scale = R_k B_j (the unscaled board point, rotated)
        d_Y_d_scale = np.einsum("nab,nb->na", R_pose[pose_of_point],
                                np.broadcast_to(self.p.board_points_m, Y.shape).reshape(-1, 3))
        d_scale = np.einsum("npa,ab,nb->np", d_pix_d_X, R_i, d_Y_d_scale).reshape(-1, 1)
        trip.add(rows, np.full((rows.size, 1), lay.slices["print_scale"].start), d_scale)
        if i > 0:
            rvec_i = np.broadcast_to(s.extrinsics[i - 1, :3], (board.shape[0], 3))
            d_X_d_ext = np.concatenate(
                [rotated_point_jacobian(rvec_i, Y.reshape(-1, 3)),
                 np.broadcast_to(np.eye(3), (board.shape[0], 3, 3))], axis=2)
            d_ext = np.einsum("npa,naw->npw", d_pix_d_X, d_X_d_ext).reshape(-1, 6)
            trip.add(rows, lay.columns("extrinsics", np.full(rows.size, i - 1), 6), d_ext)

    def _sources(self, s: BundleState) -> tuple[np.ndarray, np.ndarray]:
        """(n_src, 3) source positions R_k (P_s + D_s) + t_k and (n_src, 3, 9) their
        derivatives by pose k's (rvec, t) and by the speaker's offset D_s."""
        p = self.p
        k, spk = p.pose_of_source, p.speaker_of_source
        points = p.speakers_rig_m[spk] + s.speaker_offsets_m[spk]
        rvec = s.poses[k, :3]
        R = Rotation.from_rotvec(rvec).as_matrix()
        positions = np.einsum("sab,sb->sa", R, points) + s.poses[k, 3:]
        d_source = np.concatenate([rotated_point_jacobian(rvec, points),
                                   np.broadcast_to(np.eye(3), (k.size, 3, 3)), R], axis=2)
        return positions, d_source

    def _normals(self, s: BundleState) -> tuple[np.ndarray, np.ndarray]:
        """(n_src, 3) the rig's normal R_k z at every source and (n_src, 3, 3) its derivative
        by pose k's rvec."""
        rvec = s.poses[self.p.pose_of_source, :3]
        z = np.broadcast_to([0.0, 0.0, 1.0], rvec.shape)
        return Rotation.from_rotvec(rvec).as_matrix()[:, :, 2], rotated_point_jacobian(rvec, z)

    def _tofs(self, s: BundleState,
              geometry: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
              trip: _Triplets | None) -> np.ndarray:
        """Modelled minus measured times of flight: array microphones, then the reference.
        `geometry`: the sources, their derivatives, the rig's normals and theirs."""
        p, lay = self.p, self.layout
        sources, d_sources, normals, d_normals = geometry
        parts = []
        start = self.n_corner_rows
        d_ref = (np.zeros(p.pose_of_source.size) if p.reference_distance_m is None
                 else p.reference_distance_m)
        c_of_source = self.c_of_source
        b = s.off_axis_m
        for src, receiver, lat_col, own, measured, name in (
            (self.src, s.microphones_m[self.mic], p.latency_column[self.mic],
             s.mic_delays_s[self.mic], p.tof_s[self.tof_valid], "microphones"),
            (self.ref_valid, np.broadcast_to(s.reference_m, (self.ref_valid.size, 3)),
             np.full(self.ref_valid.size, -1), np.zeros(self.ref_valid.size),
             p.reference_tof_s[self.ref_valid], "reference"),
        ):
            diff = receiver - sources[src]
            dist = np.linalg.norm(diff, axis=1)
            unit = diff / dist[:, None]
            n = normals[src]
            cos = np.einsum("ra,ra->r", unit, n)
            off_axis = (1.0 - cos) * cos  # the acoustic centre's move, per unit of b
            lat = np.append(s.latencies_s, 0.0)[lat_col]  # column -1: the gauge board, 0
            c_col = c_of_source[src]
            c = s.speeds_of_sound_m_s[c_col]
            flight = dist - b * off_axis - d_ref[src]
            emission = s.speaker_delays_s[p.speaker_of_source[src]]
            parts.append(flight / c + d_ref[src] / p.tof_speed_of_sound_m_s + lat + own
                         + emission - measured)
            if trip is not None:
                rows = start + np.arange(src.size)
                # d(flight)/d(diff): the distance's unit vector, less b d(off_axis)/d(diff)
                d_cos_d_diff = (n - cos[:, None] * unit) / dist[:, None]
                d_off = (1.0 - 2.0 * cos)[:, None]
                grad = (unit - b * d_off * d_cos_d_diff) / c[:, None]
                index = self.mic if name == "microphones" else np.zeros(src.size, dtype=int)
                trip.add(rows, lay.columns(name, index, 3), grad)
                d_src = -np.einsum("ra,raw->rw", grad, d_sources[src])
                # the normal turns with the pose's rotation: d(cos)/d(n) = unit
                d_src[:, :3] -= (b / c * d_off[:, 0])[:, None] * np.einsum(
                    "ra,raw->rw", unit, d_normals[src])
                trip.add(rows, lay.columns("poses", p.pose_of_source[src], 6), d_src[:, :6])
                trip.add(rows, lay.columns("speaker_offsets", p.speaker_of_source[src], 3),
                         d_src[:, 6:])
                trip.add(rows, (lay.slices["c"].start + c_col)[:, None],
                         (-flight / c**2)[:, None])
                trip.add(rows, np.full((src.size, 1), lay.slices["off_axis"].start),
                         (-off_axis / c)[:, None])
                has = lat_col >= 0
                trip.add(rows[has], lay.slices["latencies"].start + lat_col[has, None],
                         np.ones((has.sum(), 1)))
                trip.add(rows, lay.slices["speaker_delays"].start
                         + p.speaker_of_source[src, None], np.ones((src.size, 1)))
                if name == "microphones":
                    trip.add(rows, lay.slices["mic_delays"].start + self.mic[:, None],
                             np.ones((src.size, 1)))
            start += src.size
        return np.concatenate(parts)

    @property
    def c_of_source(self) -> np.ndarray:
        """(n_src,) the c unknown of every source."""
        c_pose = self.p.speed_of_sound_of_pose
        if c_pose is None:
            return np.zeros(self.p.pose_of_source.size, dtype=int)
        return np.asarray(c_pose)[self.p.pose_of_source]


# ---------------------------------------------------------------------------------------------
# Priors


@dataclass(frozen=True)
class _Priors:
    """The priors as whitened linear pseudo-observations L x - b, and the unknowns they fix.

    Attributes:
        L: (n_prior, n_param) sparse, rows already divided by their standard deviation.
        b: (n_prior,) the whitened prior means.
        free: (n_param,) False for the unknowns fixed at their start (prior std FIXED).
    """

    L: sparse.csr_matrix
    b: np.ndarray
    free: np.ndarray

    @classmethod
    def of(cls, problem: BundleProblem, layout: _Layout) -> _Priors:
        n_spk = problem.speakers_rig_m.shape[0]
        priors = problem.priors or BundlePriors.none(n_spk)
        free = np.ones(layout.size, dtype=bool)
        rows: list[tuple[np.ndarray, np.ndarray, float]] = []  # (columns, weights, target)

        def prior(column: int, mean: float, std: float) -> None:
            if std == FIXED:
                free[column] = False
            else:
                rows.append((np.array([column]), np.array([1.0 / std]), mean / std))

        offsets = layout.slices["speaker_offsets"].start
        mean = np.broadcast_to(priors.speaker_offset_mean_m, (n_spk, 3))
        std = np.broadcast_to(priors.speaker_offset_std_m, (n_spk, 3))
        for j in range(n_spk):
            for a in range(3):
                prior(offsets + 3 * j + a, float(mean[j, a]), float(std[j, a]))
        emission = (np.zeros(n_spk) if priors.speaker_delay_std_s is None
                    else np.broadcast_to(priors.speaker_delay_std_s, (n_spk,)))
        for j in range(n_spk):
            prior(layout.slices["speaker_delays"].start + j, 0.0, float(emission[j]))
        prior(layout.slices["print_scale"].start, 1.0, priors.print_scale_std)
        prior(layout.slices["off_axis"].start, 0.0, priors.off_axis_std_m)
        if priors.intrinsics_mean is not None and priors.intrinsics_std is not None:
            start = layout.slices["intrinsics"].start
            for j, (mu, sd) in enumerate(zip(priors.intrinsics_mean.ravel(),
                                             priors.intrinsics_std.ravel(), strict=True)):
                if np.isfinite(sd):
                    prior(start + j, float(mu), float(sd))
        if not np.any(_measured(problem.reference_tof_s, problem.reference_std_s)):
            free[layout.slices["reference"]] = False  # no data: the stand is not in the fit
        for m in range(layout.shapes["mic_delays"][0]):
            prior(layout.slices["mic_delays"].start + m, 0.0, priors.mic_delay_std_s)
        c = layout.slices["c"]
        n_c = c.stop - c.start
        for j in range(n_c - 1):  # the air drifts slowly from pose to pose
            step = priors.speed_of_sound_step_m_s
            rows.append((np.array([c.start + j, c.start + j + 1]),
                         np.array([-1.0, 1.0]) / step, 0.0))
        if priors.speed_of_sound is not None:
            value, sd = priors.speed_of_sound
            rows.append((np.arange(c.start, c.stop), np.full(n_c, 1.0 / (n_c * sd)),
                         value / sd))
        if not rows:
            return cls(sparse.csr_matrix((0, layout.size)), np.zeros(0), free)
        cols = np.concatenate([r[0] for r in rows])
        vals = np.concatenate([r[1] for r in rows])
        row_index = np.concatenate([np.full(r[0].size, i) for i, r in enumerate(rows)])
        L = sparse.csr_matrix((vals, (row_index, cols)), shape=(len(rows), layout.size))
        return cls(L, np.array([r[2] for r in rows]), free)

    def residual(self, x: np.ndarray) -> np.ndarray:
        return self.L @ x - self.b


# ---------------------------------------------------------------------------------------------
# Noise, robust weights, Levenberg-Marquardt


def _group_norms(e: np.ndarray, width: int) -> np.ndarray:
    """|e| of every residual group (a corner's pixel pair: width 2), repeated per row."""
    return np.repeat(np.linalg.norm(e.reshape(-1, width), axis=1), width)


def _estimate_sigmas(model: _Model, residual: np.ndarray, keep: np.ndarray,
                     at_least_the_family: bool = False) -> np.ndarray:
    """(n_rows,) sigma of every residual: its base sigma times its group's scale, the robust
    scatter (1.4826 x median absolute value) of the group's kept residuals in base units.
    Why from the data: the corner noise depends on the blur and the board's size in the
    image, the TOF noise on reflections and model errors that the predicted std leaves out.

    With `at_least_the_family`, a group's scale is never below its family's (all of the
    family's kept residuals pooled): what the outliers are judged by. A microphone's scale
    from few sources is itself noisy (48 TOFs at 8 poses: about 12 %), and one drawn low
    took Gaussian residuals of 3.4 and 3.8 sigmas for 5-sigma outliers in the ideal world;
    left out, they no longer pulled on the fit and looked worse with each pass."""
    scales = {}
    for g in model.groups:
        kept = keep[g.index]
        e = residual[g.index][kept] / g.base_sigma[kept]
        scales[g.name] = (e, robust_sigma(e, floor=1e-12) if e.size else 1.0)
    family = {}
    if at_least_the_family:
        for name in {g.family for g in model.groups}:
            pooled = np.concatenate([scales[g.name][0] for g in model.groups
                                     if g.family == name])
            family[name] = robust_sigma(pooled, floor=1e-12) if pooled.size else 1.0
    sigma = np.ones(model.n_rows)
    for g in model.groups:
        sigma[g.index] = g.base_sigma * max(scales[g.name][1], family.get(g.family, 0.0))
    return sigma


def _huber(e: np.ndarray, widths: np.ndarray, k: float) -> tuple[np.ndarray, float]:
    """IRLS weights (n_rows,) and the Huber cost of whitened residuals e, group by group."""
    norm = np.abs(e)
    pairs = widths == 2
    norm[pairs] = _group_norms(e[pairs], 2)
    weight = np.where(norm <= k, 1.0, k / np.maximum(norm, k))
    rho = np.where(norm <= k, norm**2, 2 * k * norm - k**2)
    return weight, float(np.sum(rho / np.where(widths == 2, 2.0, 1.0)))


class _Pass:
    """One robust Levenberg-Marquardt pass with fixed sigmas and a fixed set of kept rows; the
    priors enter as whitened Gaussian pseudo-observations and only the free unknowns move."""

    def __init__(self, model: _Model, sigma: np.ndarray, keep: np.ndarray,
                 priors: _Priors, options: BundleOptions) -> None:
        self.model, self.priors, self.options = model, priors, options
        self.whiten = np.where(keep, 1.0 / sigma, 0.0)
        self.widths = np.ones(model.n_rows, dtype=int)
        for g in model.groups:
            self.widths[g.index] = g.width
        self.free = np.flatnonzero(priors.free)

    def cost(self, residual: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, float]:
        """Huber weights of the data rows and the total cost (data plus priors)."""
        weight, data = _huber(residual * self.whiten, self.widths, self.options.huber_k)
        prior = self.priors.residual(x)
        return weight, data + float(prior @ prior)

    def normal_equations(self, residual: np.ndarray, jac: sparse.csr_matrix,
                         x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """J^T W J + L^T L (dense) and J^T W r + L^T (L x - b) over the free unknowns, W the
        whitening squared times the Huber weights."""
        weight, _ = self.cost(residual, x)
        w = self.whiten**2 * weight
        L = self.priors.L
        bounds = [int(b) for b in np.linspace(0, jac.shape[0], default_workers() + 1)]
        with ThreadPoolExecutor(len(bounds) - 1) as pool:  # SciPy's products release the GIL
            parts = pool.map(lambda i: _weighted_gram(jac, w, bounds[i], bounds[i + 1]),
                             range(len(bounds) - 1))
            A = (L.T @ L).toarray() + sum(parts)
        g = jac.T @ (w * residual) + L.T @ self.priors.residual(x)
        return A[np.ix_(self.free, self.free)], g[self.free]

    def run(self, x: np.ndarray) -> tuple[np.ndarray, int]:
        """Iterate from x until the robust cost stops decreasing; return x and iterations."""
        residual, jac = self.model.evaluate(x, jacobian=True)
        cost = self.cost(residual, x)[1]
        damping = 1e-4
        for iteration in range(1, self.options.max_iterations + 1):
            A, g = self.normal_equations(residual, jac, x)
            scale = np.sqrt(np.maximum(np.diag(A), 1e-300))
            A_s = A / scale / scale[:, None]
            while True:
                step = _solve_spd(A_s + damping * np.eye(A.shape[0]), -g / scale) / scale
                trial = x.copy()
                trial[self.free] += step
                trial_residual, _ = self.model.evaluate(trial, jacobian=False)
                trial_cost = self.cost(trial_residual, trial)[1]
                if trial_cost <= cost or damping > 1e12:
                    break
                damping *= 10.0
            if trial_cost > cost:
                return x, iteration
            decrease = cost - trial_cost
            x, cost = trial, trial_cost
            damping = max(damping / 10.0, 1e-9)
            residual, jac = self.model.evaluate(x, jacobian=True)
            if decrease <= self.options.tolerance * cost:
                return x, iteration
        return x, self.options.max_iterations

    def leverages(self, residual: np.ndarray, jac: sparse.csr_matrix, x: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The inverse normal matrix over the free unknowns, the rows' weights (whitening
        squared times Huber's; zero for the rows left out) and their leverages (n_rows,):
        h = w j^T A^-1 j, the share of its own residual the fit absorbs (they sum to the
        number of unknowns the data determine)."""
        A, _ = self.normal_equations(residual, jac, x)
        A_inv = inverse_normal(A)
        weight, _ = self.cost(residual, x)
        w = weight * self.whiten**2
        free_jac = jac.tocsc()[:, self.free].tocsr()
        return A_inv, w, w * _quadratic_forms(free_jac, A_inv)

    def covariance(self, residual: np.ndarray, jac: sparse.csr_matrix,
                   x: np.ndarray) -> np.ndarray:
        """(n_param, n_param) covariance over the free unknowns (the fixed ones have zero rows
        and columns): the cluster-robust sandwich A^-1 B A^-1, A the normal matrix (data and
        priors), B the priors' L^T L plus the sum over the error clusters
        (`_Model.clusters`) of g g^T, g the cluster's share of the gradient (its whitened,
        Huber-weighted residuals times their Jacobian rows).

        Why not A^-1 alone: that assumes independent rows of exactly the estimated sigma.
        The residuals of the realistic lab are heavier-tailed than the robust sigma's Gaussian
        (their mean square is about 1.15 of it) and correlated within a pose's speakers; the
        sandwich takes both from the residuals themselves. Each cluster's residuals are divided
        by sqrt(1 - h), h its leverage (the share of its own residuals that the fit absorbs,
        about 4 / 30 for a microphone's cluster at 30 poses), as in the CR2 estimator: on
        synthetic scenes with independent Gaussian noise the microphones' errors relative to
        the array then have the squared Mahalanobis distance they should (3.1 for 3), where
        the plain sandwich gave 5.1 (tests/calibration/test_bundle.py)."""
        A_inv, w, h = self.leverages(residual, jac, x)
        clusters = self.model.clusters()
        leverage = np.bincount(clusters, h)
        score = w * residual / np.sqrt(1.0 - np.minimum(leverage, _MAX_LEVERAGE))[clusters]
        sums = sparse.csr_matrix((score, (clusters, np.arange(score.size))),
                                 shape=(int(clusters.max()) + 1, score.size))
        g = (sums @ jac).tocsc()[:, self.free]
        L = self.priors.L.tocsc()[:, self.free]
        meat = (g.T @ g).toarray() + (L.T @ L).toarray()
        out = np.zeros((x.size, x.size))
        out[np.ix_(self.free, self.free)] = A_inv @ meat @ A_inv
        return out


_MAX_LEVERAGE = 0.9
"""A cluster's leverage is capped here (a cluster that alone decides an unknown has h near 1,
and its residual says nothing of that unknown's error)."""


def _quadratic_forms(rows: sparse.csr_matrix, M: np.ndarray, chunk: int = 8192
                     ) -> np.ndarray:
    """(n_rows,) j^T M j for every row j of a sparse matrix, M dense symmetric: each row's
    nonzeros against the block of M they select, in chunks of rows padded to the widest."""
    counts = np.diff(rows.indptr)
    width = int(counts.max(initial=0))
    out = np.zeros(rows.shape[0])
    if width == 0:
        return out
    for start in range(0, rows.shape[0], chunk):
        stop = min(start + chunk, rows.shape[0])
        n = counts[start:stop]
        slot = np.arange(width) < n[:, None]  # (rows, width): which slots hold a nonzero
        cols = np.zeros((stop - start, width), dtype=np.intp)
        vals = np.zeros((stop - start, width))
        lo, hi = rows.indptr[start], rows.indptr[stop]
        cols[slot] = rows.indices[lo:hi]
        vals[slot] = rows.data[lo:hi]
        block = M[cols[:, :, None], cols[:, None, :]]  # (rows, width, width)
        out[start:stop] = np.einsum("ra,rab,rb->r", vals, block, vals)
    return out


def _weighted_gram(jac: sparse.csr_matrix, w: np.ndarray, start: int, stop: int
                   ) -> np.ndarray:
    """J^T diag(w) J (dense) of the rows start:stop of `jac`: the normal matrix's share of
    those rows, which a thread per core computes (J^T W J is a third of the joint fit's time at
    140 poses)."""
    p0, p1 = jac.indptr[start], jac.indptr[stop]
    rows = sparse.csr_matrix((jac.data[p0:p1], jac.indices[p0:p1],
                              jac.indptr[start:stop + 1] - p0), shape=(stop - start, jac.shape[1]))
    weighted = rows.copy()
    weighted.data *= np.repeat(w[start:stop], np.diff(rows.indptr))  # W J
    return (rows.T @ weighted).toarray()


def _solve_spd(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve A y = b for symmetric positive (semi)definite A; least squares if singular."""
    try:
        return cho_solve(cho_factor(A), b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


# ---------------------------------------------------------------------------------------------
# The fit


def fit_bundle(problem: BundleProblem, start: BundleState,
               options: BundleOptions | None = None) -> BundleSolution:
    """The joint fit of cameras, board poses, microphones, c, latencies and, with their
    priors (problem.priors), the microphones' own delays, the speakers' rig offsets and the
    print scale.

    Passes of robust Levenberg-Marquardt, the first with sigmas estimated from the start's
    residuals, each next one with the sigmas re-estimated from the previous pass's residuals
    and its outliers left out, until the sigmas change by less than `sigma_tolerance` and the
    outliers not at all; then a final pass with those sigmas and outliers, converged to
    `tolerance` (the ones before stop at the looser `pass_tolerance`). Why more than two: the
    start's residuals hold the frozen camera's systematic error, so the first TOF sigma is
    far too large (the first pass then sides with the corners), and each pass gets closer to
    the noise. The covariance is the final pass's cluster-robust sandwich.

    `start` may leave the optional unknowns None (zeros) and give one c for all poses.

    Raises:
        ValueError: the problem's arrays disagree in shape with the start.
    """
    options = options or BundleOptions()
    start = _completed(problem, start)
    _check(problem, start)
    with single_threaded_blas():
        return _fit(problem, start, options)


def _completed(problem: BundleProblem, start: BundleState) -> BundleState:
    """`start` with its optional unknowns filled in and its c repeated per pose if needed."""
    state = start.completed(problem.speakers_rig_m.shape[0])
    c = state.speeds_of_sound_m_s
    if c.size == 1 and problem.n_speed_of_sound > 1:
        state = replace(state, speeds_of_sound_m_s=np.full(problem.n_speed_of_sound, c[0]))
    return state


def _fit(problem: BundleProblem, start: BundleState, options: BundleOptions) -> BundleSolution:
    """`fit_bundle` after the checks."""
    layout = _Layout.of(start)
    model = _Model(problem, layout)
    priors = _Priors.of(problem, layout)
    x = layout.pack(start)
    keep = model.measured.copy()
    sigma = _estimate_sigmas(model, model.evaluate(x, jacobian=False)[0], keep)
    iterations = 0
    settling = replace(options, tolerance=options.pass_tolerance)
    for _ in range(options.max_passes):
        x, n = _Pass(model, sigma, keep, priors, settling).run(x)
        iterations += n
        residual = model.evaluate(x, jacobian=False)[0]
        new_keep = _inliers(model, residual / _estimate_sigmas(model, residual, keep, True),
                            options.outlier_threshold)
        new_sigma = _estimate_sigmas(model, residual, new_keep)
        settled = (np.max(np.abs(new_sigma / sigma - 1.0)) < options.sigma_tolerance
                   and np.array_equal(new_keep, keep))
        sigma, keep = new_sigma, new_keep
        if settled:
            break
    sigma = _corner_sigmas_for_leverage(model, _Pass(model, sigma, keep, priors, options), x,
                                        sigma, keep)
    final = _Pass(model, sigma, keep, priors, options)
    x, n = final.run(x)
    iterations += n
    residual, jac = model.evaluate(x, jacobian=True)
    covariance = final.covariance(residual, jac, x)
    e = residual * final.whiten
    prior = priors.residual(x)
    dof = max(int(keep.sum()) + prior.size - int(priors.free.sum()), 1)
    return _solution(model, x, residual, keep, sigma, covariance,
                     float(e @ e + prior @ prior) / dof, iterations)


def _corner_sigmas_for_leverage(model: _Model, settled: _Pass, x: np.ndarray,
                                sigma: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """`sigma` with the cameras' corner sigmas estimated again from residuals standardized
    by their leverage, r / sqrt(1 - h) (`_Pass.leverages`).

    Why: the fit absorbs part of the noise (each view's pose, a share of its camera's
    intrinsics): a corner's residual has variance sigma^2 (1 - h), so the scatter of the
    plain residuals underestimates the noise by sqrt(1 - p / n), p of n rows' worth of
    unknowns (2-3 % for a camera's corners; the camera calibration's figure,
    calibration.camera.corner_noise, has the same correction). The times of flight keep theirs."""
    residual, jac = model.evaluate(x, jacobian=True)
    h = settled.leverages(residual, jac, x)[2]
    corners = np.arange(model.n_rows) < model.n_corner_rows
    standardized = np.where(corners, residual / np.sqrt(1.0 - np.minimum(h, _MAX_LEVERAGE)),
                            residual)
    return np.where(corners, _estimate_sigmas(model, standardized, keep), sigma)


def _check(problem: BundleProblem, start: BundleState) -> None:
    n_mic = problem.tof_s.shape[1]
    expected = {
        "intrinsics": ((problem.n_camera, N_INTRINSICS), start.intrinsics.shape),
        "extrinsics": ((problem.n_camera - 1, 6), start.extrinsics.shape),
        "microphones": ((n_mic, 3), start.microphones_m.shape),
        "latencies": ((problem.n_latency,), start.latencies_s.shape),
        "speeds of sound": ((problem.n_speed_of_sound,), start.speeds_of_sound_m_s.shape),
    }
    for name, (want, got) in expected.items():
        if want != got:
            raise ValueError(f"bundle start: {name} has shape {got}, the problem needs {want}")
    if max(problem.view_pose.max(), problem.pose_of_source.max()) >= len(start.poses):
        raise ValueError(f"bundle start has {len(start.poses)} poses; the views or sources "
                         "refer to more")


def _inliers(model: _Model, e: np.ndarray, threshold: float) -> np.ndarray:
    """Rows with a measurement whose whitened residual group is within `threshold`
    sigmas."""
    keep = model.measured.copy()
    for g in model.groups:
        keep[g.index] &= _group_norms(e[g.index], g.width) <= threshold
    return keep


def _solution(model: _Model, x: np.ndarray, residual: np.ndarray, keep: np.ndarray,
              sigma: np.ndarray, covariance: np.ndarray, chi2: float,
              iterations: int) -> BundleSolution:
    p, lay = model.p, model.layout
    n_view, n_corner = p.corners_px.shape[:2]
    n_c = model.n_corner_rows
    tof_res = np.full(p.tof_s.shape, np.nan)
    tof_res[model.tof_valid] = -residual[n_c:n_c + model.src.size]
    tof_out = np.zeros(p.tof_s.shape, dtype=bool)
    tof_out[model.tof_valid] = ~keep[n_c:n_c + model.src.size]
    ref_res = np.full(p.reference_tof_s.shape, np.nan)
    ref_res[model.ref_valid] = -residual[n_c + model.src.size:]
    ref_out = np.zeros(p.reference_tof_s.shape, dtype=bool)
    ref_out[model.ref_valid] = ~keep[n_c + model.src.size:]
    lacking = np.asarray(~model.measured[:n_c].reshape(n_view, n_corner, 2).all(axis=2))
    corner_res = np.where(lacking[..., None], np.nan,
                          -residual[:n_c].reshape(n_view, n_corner, 2))
    corner_out = np.asarray(~keep[:n_c].reshape(n_view, n_corner, 2).all(axis=2)) & ~lacking
    sq = np.where(corner_out | lacking, np.nan, np.sum(corner_res**2, axis=2))
    corner_rms = np.array([np.sqrt(np.nanmean(sq[p.view_camera == i]))
                           for i in range(p.n_camera)])
    sigmas, per_mic = {}, []
    for g in model.groups:
        if g.index.size:
            scale = float(sigma[g.index[0]] / g.base_sigma[0])
            if g.name.startswith(f"{GROUP_TOF} "):
                per_mic.append(scale)
            else:
                sigmas[g.name] = scale
    if per_mic:
        sigmas[GROUP_TOF] = float(np.median(per_mic))
    return BundleSolution(
        state=lay.unpack(x),
        std=lay.unpack(np.sqrt(np.maximum(np.diag(covariance), 0.0))),
        covariance=covariance,
        parameter_slices=dict(lay.slices),
        sigmas=sigmas,
        corner_residuals_px=corner_res,
        tof_residuals_s=tof_res,
        reference_residuals_s=ref_res,
        corner_outliers=corner_out,
        corner_rms_px=corner_rms,
        tof_outliers=tof_out,
        reference_outliers=ref_out,
        chi2_per_dof=chi2,
        iterations=iterations,
        speed_of_sound_of_pose=p.speed_of_sound_of_pose,
    )


# ---------------------------------------------------------------------------------------------
# To and from the camera calibration


def camera_start(cams: CameraCalibration) -> tuple[np.ndarray, np.ndarray]:
    """(n_camera, 9) intrinsics and (n_camera - 1, 6) extrinsics of a camera calibration, in
    its camera order (camera 0 first)."""
    names = list(cams.intrinsics)
    intrinsics = np.array([[*_focal_centre(cams.intrinsics[n].K), *cams.intrinsics[n].dist]
                           for n in names])  # fmt: skip
    extrinsics = np.array([cams.cam_from_cam0[n].cam0_to_cam.params
                           for n in names[1:]]).reshape(-1, 6)
    return intrinsics, extrinsics


def _focal_centre(K: np.ndarray) -> tuple[float, float, float, float]:
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])


def board_views(cams: CameraCalibration,
                steps: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(view_camera, view_pose, corners_px) of every view of `steps` (pose index = position
    in `steps`) by the calibrated cameras."""
    keys = _view_keys(cams, steps)
    corners = np.array([cams.views[key].corners_px for key, _ in keys])
    view_camera, view_pose = (np.array(v) for v in zip(*(ik for _, ik in keys), strict=True))
    return view_camera, view_pose, corners


def view_sigmas(cams: CameraCalibration, steps: list[str]) -> np.ndarray:
    """(n_view,) the corner noise of every view of `board_views`, in its order, pixels per
    coordinate (`BoardView.sigma_px`: `BundleProblem.corner_sigma_px`)."""
    return np.array([cams.views[key].sigma_px for key, _ in _view_keys(cams, steps)])


def _view_keys(cams: CameraCalibration, steps: list[str]
               ) -> list[tuple[tuple[str, str], tuple[int, int]]]:
    """((camera, step), (camera index, pose index)) of every view of `steps`, pose by pose."""
    names = list(cams.intrinsics)
    keys = [((name, step), (i, k)) for k, step in enumerate(steps)
            for i, name in enumerate(names) if (name, step) in cams.views]  # fmt: skip
    if not keys:
        raise ValueError("no board view of the given steps: nothing to fit the cameras to")
    return keys


def refined_cameras(cams: CameraCalibration, solution: BundleSolution) -> CameraCalibration:
    """The camera calibration with the joint fit's intrinsics (and their covariance) and
    extrinsics; the per-view poses, missed images and the rest are the camera-only ones."""
    names = list(cams.intrinsics)
    state = solution.state
    intrinsics, extrinsics = {}, {}
    for i, name in enumerate(names):
        old = cams.intrinsics[name]
        fx, fy, cx, cy = state.intrinsics[i, :4]
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        rms = float(solution.corner_rms_px[i])
        intrinsics[name] = CameraIntrinsics(
            name, old.width, old.height, K, state.intrinsics[i, 4:].copy(),
            solution.marginal("intrinsics", i, N_INTRINSICS).copy(), rms, old.n_views,
            old.noise)
        old_ext = cams.cam_from_cam0[name]
        if i == 0:
            extrinsics[name] = old_ext
        else:
            # made from R, not from_rotvec: result.json writes the rotation vector of R
            cam0_to_cam = RigidTransform(rotation_from_rotvec(state.extrinsics[i - 1, :3]),
                                         state.extrinsics[i - 1, 3:].copy())
            extrinsics[name] = Extrinsics(cam0_to_cam, rms, old_ext.n_shared_views, old_ext.via)
    return CameraCalibration(cams.board, intrinsics, extrinsics, cams.views, cams.missed,
                             cams.uncalibrated, bow=cams.bow)


def pose_estimate(solution: BundleSolution, index: int) -> Pose:
    """Board pose `index` (rig -> camera 0) of the joint fit with its 6x6 covariance."""
    p = solution.state.poses[index]
    return Pose(RigidTransform.from_rotvec(p[:3], p[3:].copy()),
                solution.marginal("poses", index, 6).copy())
