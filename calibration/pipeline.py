"""The calibration pipeline: from a capture session to microphone coordinates in the
camera-0 frame (paper sections IV-D to IV-I), one stage after another.

Stages (each timed): cameras (intrinsics, board poses, stereo), speaker positions per pose
(eq. 10) and the reference microphone's position, times of flight, the speed of sound from the
reference microphone (IV-G), the microphone solver (eq. 15; or the paper's own search as a
baseline with `method="paper"`) with the cameras frozen, and last the joint fit
(calibration.bundle): cameras, board poses, microphones, c and latencies refined together,
started from the camera-frozen solution, which is kept and reported beside it.

Choices made here, and why (see docs/calibration.md for the figures behind them):
- latencies: one per board, fitted. The reference microphone records on its own board, so every
  array board's latency is relative to it; they are a few microseconds (0.36 mm of bias per
  microsecond if ignored) and, per board, cheap to fit.
- speed of sound: fixed at the reference-microphone fit when the session has one. That fit
  sees the same camera scale as the speaker positions (so c absorbs a checkerboard or focal
  length scale error, as the paper intends) and is far more precise than the same c fitted
  inside the solver, where it trades off against every microphone's range. The solver's own c
  is still computed and reported beside it. (The joint fit, on by default, fits c itself:
  there the cameras' scale is corrected by the times of flight instead of absorbed by c.)
- joint fit: on by default because, against the simulated truth, it removes the common depth
  offset a frozen camera's focal-length error leaves in the array (0.38 -> 0.01 mm mean error
  on a 30-pose sphere72 session; benchmarks/bench_bundle.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from .bundle import (
    GROUP_TOF,
    BundleProblem,
    BundleSolution,
    BundleState,
    board_views,
    camera_start,
    fit_bundle,
    pose_estimate,
    refined_cameras,
)
from .cameras import CameraCalibration, calibrate_session
from .result import (
    CalibrationResult,
    CameraFrozenResult,
    CameraResult,
    JointFitResult,
    MicrophoneResult,
    PoseResult,
    ResidualStats,
    SpeedOfSoundReference,
    TofQuality,
    TransformResult,
)
from .session_data import CalibrationInputError, SessionData, load_session
from .solver import (
    MicrophoneSolution,
    PriorGeometry,
    RigSources,
    SolverOptions,
    latency_columns,
    multilaterate,
    solve_microphones,
    solve_paper_method,
)
from .speakers import (
    ReferenceMicrophonePosition,
    RigPoseInCam0,
    SpeakerLocationError,
    SpeakerPositions,
    reference_microphone_position,
    speaker_positions,
)
from .speed_of_sound import SpeedOfSoundFit, fit_speed_of_sound
from .times_of_flight import SessionTofs, measure_session_tofs

NOMINAL_SPEED_OF_SOUND_M_S = 343.0
"""Start value of c when nothing better is known (about 20 degC)."""

JOINT_NOTE = (
    "Final fit: the optical-acoustic bundle adjustment (cameras, board poses, microphones, c "
    "and latencies fitted to the corner pixels and the times of flight together); the "
    "camera-frozen solution it started from is under camera_frozen. Gauges: the camera-0 "
    "frame, the checkerboard's printed scale, latency 0 for the reference microphone's board."
)
CONFOUND_NOTE = (
    "The speed of sound and the camera's metric scale are confounded: scaling every source "
    "position and c by the same factor leaves every time of flight unchanged, so c is "
    "'scaled' c (paper IV-G). An error in the checkerboard's printed size or in the focal "
    "length moves c, not the microphones."
)


@dataclass(frozen=True)
class CalibrationOptions:
    """Options of `calibrate`.

    Attributes:
        method: "micam" (the sparse robust solver) or "paper" (section IV-I's coordinate search
            from zeros, c fixed, no latency; the baseline).
        latency: "per_board", "common" or "none".
        speed_of_sound: "reference" (fixed at the reference-microphone fit; falls back to
            "solve" without a refmic image) or "solve" (an unknown of the solver).
        refine_poses: fit a rigid correction per rig pose, weighted by the camera's pose
            covariance.
        band_hz: the band the times of flight are estimated in (the speaker band).
        phat: GCC-PHAT weighting of the correlations.
        allow_interrupted: calibrate the completed poses of an interrupted session.
        joint: finish with the optical-acoustic bundle adjustment (method "micam" only); the
            camera-frozen solution is reported beside it.
        prior: a known geometry of the array in its own frame (CAD or an earlier
            calibration), in the session's microphone order: the solver then fits its rigid
            transform R_m, T_m into the camera-0 frame (paper IV-H), and each microphone's
            deviation from it if the prior has a deviation std. Method "micam" only.
    """

    method: Literal["micam", "paper"] = "micam"
    latency: Literal["per_board", "common", "none"] = "per_board"
    speed_of_sound: Literal["reference", "solve"] = "reference"
    refine_poses: bool = False
    band_hz: tuple[float, float] = (300.0, 20_000.0)
    phat: bool = False
    allow_interrupted: bool = False
    joint: bool = True
    prior: PriorGeometry | None = None


@dataclass
class Measurements:
    """Everything the solver works from: the session, the cameras, the speaker positions,
    the times of flight and the reference-microphone fit of c."""

    data: SessionData
    cameras: CameraCalibration
    speakers: SpeakerPositions
    located: list[int]
    tofs: SessionTofs
    reference: ReferenceMicrophonePosition | None
    reference_fit: SpeedOfSoundFit | None
    timings_s: dict[str, float] = field(default_factory=dict)


@dataclass
class CalibrationRun:
    """A finished calibration: the result and what the report draws from.

    Attributes:
        result: the result (the joint fit's when it ran).
        measurements: the measurements the result is from (with the joint fit's cameras and
            speaker positions when it ran).
        solution: the microphones of the result.
        camera_frozen: the camera-frozen solution, when the joint fit replaced it.
        bundle: the joint fit, when it ran.
    """

    result: CalibrationResult
    measurements: Measurements
    solution: MicrophoneSolution
    camera_frozen: MicrophoneSolution | None = None
    bundle: BundleSolution | None = None

    @property
    def data(self) -> SessionData:
        return self.measurements.data

    @property
    def speakers(self) -> SpeakerPositions:
        return self.measurements.speakers

    @property
    def tofs(self) -> SessionTofs:
        return self.measurements.tofs


def _timed(timings: dict[str, float], name: str, on_stage: Callable[[str], None] | None):
    """Context manager that tells `on_stage` and records the stage's duration in seconds."""

    class _Stage:
        def __enter__(self) -> None:
            if on_stage is not None:
                on_stage(name)
            self.t0 = time.perf_counter()

        def __exit__(self, *exc: object) -> None:
            timings[name] = round(time.perf_counter() - self.t0, 3)

    return _Stage()


def measure(path: Path, options: CalibrationOptions | None = None,
            on_stage: Callable[[str], None] | None = None) -> Measurements:
    """Every measurement of a session: cameras, speaker positions, times of flight, and the
    speed of sound from the reference microphone (when the session has its image)."""
    options = options or CalibrationOptions()
    timings: dict[str, float] = {}
    with _timed(timings, "load", on_stage):
        data = load_session(path, options.allow_interrupted)
    with _timed(timings, "cameras", on_stage):
        cams = calibrate_session(data.reader)
    with _timed(timings, "speakers", on_stage):
        speakers = speaker_positions(cams, data.speakers_rig_m, data.pose_steps)
        reference = _reference_position(cams, data)
    with _timed(timings, "times of flight", on_stage):
        tofs = measure_session_tofs(data, NOMINAL_SPEED_OF_SOUND_M_S, options.band_hz,
                                    options.phat)
    located = [data.pose_steps.index(p.step) for p in speakers.poses]
    reference_fit = None
    if reference is not None:
        distances = np.linalg.norm(speakers.positions_m - reference.position_m, axis=2)
        reference_fit = fit_speed_of_sound(distances.ravel(),
                                           tofs.reference_tof_s[located].ravel())
    return Measurements(data, cams, speakers, located, tofs, reference, reference_fit, timings)


def calibrate(path: Path, options: CalibrationOptions | None = None,
              on_stage: Callable[[str], None] | None = None) -> CalibrationRun:
    """Calibrate the session at `path`. `on_stage` is told the name of each stage as it starts.

    Raises CalibrationInputError (or the cameras' and speakers' own errors, all ValueError)
    with a message that says what is missing.
    """
    options = options or CalibrationOptions()
    return calibrate_measured(measure(path, options, on_stage), options, on_stage=on_stage)


def calibrate_measured(m: Measurements, options: CalibrationOptions,
                       poses: np.ndarray | None = None,
                       on_stage: Callable[[str], None] | None = None) -> CalibrationRun:
    """The solver and the joint fit of `calibrate` on measurements already made, from all
    located poses or from a subset (`poses`, indices into `m.speakers.poses`: the acoustic
    sources; every board view still constrains the cameras, and every pose gets a board pose,
    so the others can be imaged with the result as held-out data)."""
    timings = dict(m.timings_s)
    with _timed(timings, "solver", on_stage):
        solution = solve(m, options, poses)
    if not (options.joint and options.method == "micam"):
        return CalibrationRun(_assemble(m, solution, options, timings), m, solution)
    with _timed(timings, "joint fit", on_stage):
        bundle = fit_joint(m, solution, options, poses)
        joint_m, joint_solution = joint_measurements(m, bundle, solution, options)
    result = _assemble(joint_m, joint_solution, options, timings)
    result = result.model_copy(update={
        "camera_frozen": _frozen_summary(m, solution),
        "joint_fit": _joint_summary(m, bundle),
        "notes": [*result.notes, JOINT_NOTE],
    })
    return CalibrationRun(result, joint_m, joint_solution, solution, bundle)


def _reference_position(cams: CameraCalibration,
                        data: SessionData) -> ReferenceMicrophonePosition | None:
    if "refmic" not in data.reader.steps():
        return None
    try:
        return reference_microphone_position(cams, np.array(data.config.rig.reference_mark_m))
    except SpeakerLocationError:
        return None


def _rig_sources(data: SessionData, speakers: SpeakerPositions, pose_idx: np.ndarray,
                 spk_idx: np.ndarray) -> RigSources:
    """The sources of the chosen poses and speakers, pose after pose."""
    poses = [speakers.poses[i] for i in pose_idx]
    return RigSources(
        rig_points_m=data.speakers_rig_m,
        rotvec=np.array([p.rig_to_cam0.rvec for p in poses]),
        translation_m=np.array([p.rig_to_cam0.tvec for p in poses]),
        pose_of_source=np.repeat(np.arange(len(poses)), len(spk_idx)),
        speaker_of_source=np.tile(spk_idx, len(poses)),
        pose_covariance=np.array([p.rig_to_cam0.cov for p in poses]),
    )


def board_indices(data: SessionData) -> tuple[list[str], np.ndarray]:
    """The array boards (sorted serials) and each microphone's index into them."""
    boards = sorted(set(data.mic_boards))
    return boards, np.array([boards.index(b) for b in data.mic_boards])


def solve(m: Measurements, options: CalibrationOptions,
          poses: np.ndarray | None = None,
          speakers_used: np.ndarray | None = None) -> MicrophoneSolution:
    """Solve for the microphones from the measurements, optionally from a subset of the
    located poses (indices into `m.speakers.poses`) and of the speakers (indices)."""
    data = m.data
    n_mic = len(data.mic_ids)
    pose_idx = np.arange(len(m.located)) if poses is None else np.asarray(poses)
    spk_idx = np.arange(data.n_speakers) if speakers_used is None else np.asarray(speakers_used)
    rows = np.asarray(m.located)[pose_idx]
    tof = m.tofs.tof_s[rows][:, spk_idx].reshape(-1, n_mic)
    std = m.tofs.std_s[rows][:, spk_idx].reshape(-1, n_mic)
    sources = _rig_sources(data, m.speakers, pose_idx, spk_idx)
    c_known = m.reference_fit is not None and options.speed_of_sound == "reference"
    c0 = (m.reference_fit.speed_of_sound_m_s if m.reference_fit is not None
          else NOMINAL_SPEED_OF_SOUND_M_S)
    boards, board_of_mic = board_indices(data)
    ref_board = data.config.reference.board
    solver_options = SolverOptions(
        speed_of_sound_m_s=c0,
        fit_speed_of_sound=not c_known,
        latency=options.latency,
        reference_board=boards.index(ref_board) if ref_board in boards else None,
        refine_poses=options.refine_poses,
    )
    if options.method == "paper":
        return solve_paper_method(sources, tof, std, solver_options)
    return solve_microphones(sources, tof, std, board_of_mic=board_of_mic,
                             options=solver_options, prior_geometry=options.prior)


def _bundle_steps(m: Measurements) -> tuple[list[str], list[RigPoseInCam0]]:
    """The board poses of the joint fit: the located pose steps, then the reference-microphone
    step when it was located (its corners constrain the cameras too)."""
    poses = list(m.speakers.poses)
    if m.reference is not None:
        poses.append(m.reference.pose)
    return [p.step for p in poses], poses


def _latency_layout(data: SessionData, options: CalibrationOptions) -> tuple[np.ndarray, int]:
    """Latency column of every array board (-1: the gauge board, when it records array
    microphones too) and the number of latency unknowns, for the latency model of `options`."""
    boards, _ = board_indices(data)
    ref_board = data.config.reference.board
    return latency_columns(len(boards), SolverOptions(
        latency=options.latency,
        reference_board=boards.index(ref_board) if ref_board in boards else None))


def fit_joint(m: Measurements, frozen: MicrophoneSolution, options: CalibrationOptions,
              poses: np.ndarray | None = None, speakers: np.ndarray | None = None
              ) -> BundleSolution:
    """The optical-acoustic bundle adjustment, started from the camera-frozen solution.

    Microphones the frozen solver could not place (too few measurements) are left out. The
    reference microphone's start is multilaterated from its times of flight (its board is the
    latency gauge, so no latency). `poses` (indices into the located poses) and `speakers`
    restrict the acoustic sources to a subset (as `solve` does); every board view still
    constrains the cameras, as in a calibration that uses all its images.
    """
    data = m.data
    solved = np.flatnonzero(np.all(np.isfinite(frozen.positions_m), axis=1))
    steps, board_poses = _bundle_steps(m)
    view_camera, view_pose, corners = board_views(m.cameras, steps)
    pose_idx = np.arange(len(m.located)) if poses is None else np.asarray(poses)
    speaker_idx = np.arange(data.n_speakers) if speakers is None else np.asarray(speakers)
    rows = np.asarray(m.located)[pose_idx]
    n_mic = len(data.mic_ids)
    board_column, n_latency = _latency_layout(data, options)
    latency_column = board_column[board_indices(data)[1]]
    problem = BundleProblem(
        board_points_m=m.cameras.board.object_points(),
        speakers_rig_m=data.speakers_rig_m,
        view_camera=view_camera, view_pose=view_pose, corners_px=corners,
        pose_of_source=np.repeat(pose_idx, speaker_idx.size),
        speaker_of_source=np.tile(speaker_idx, pose_idx.size),
        tof_s=m.tofs.tof_s[rows][:, speaker_idx].reshape(-1, n_mic)[:, solved],
        tof_std_s=m.tofs.std_s[rows][:, speaker_idx].reshape(-1, n_mic)[:, solved],
        reference_tof_s=m.tofs.reference_tof_s[rows][:, speaker_idx].ravel(),
        reference_std_s=m.tofs.reference_std_s[rows][:, speaker_idx].ravel(),
        latency_column=latency_column[solved], n_latency=n_latency,
        camera_names=tuple(m.cameras.intrinsics),
    )  # fmt: skip
    sources = _rig_sources(data, m.speakers, pose_idx, speaker_idx).positions()
    reference = multilaterate(sources, frozen.speed_of_sound_m_s
                              * problem.reference_tof_s[:, None])[0]
    latencies = np.zeros(n_latency)
    latencies[board_column[board_column >= 0]] = frozen.latency_s[board_column >= 0]
    intrinsics, extrinsics = camera_start(m.cameras)
    start = BundleState(
        intrinsics=intrinsics, extrinsics=extrinsics,
        poses=np.array([[*p.rig_to_cam0.rvec, *p.rig_to_cam0.tvec] for p in board_poses]),
        microphones_m=frozen.positions_m[solved], reference_m=reference,
        speed_of_sound_m_s=frozen.speed_of_sound_m_s, latencies_s=latencies,
    )  # fmt: skip
    return fit_bundle(problem, start)


def joint_measurements(m: Measurements, bundle: BundleSolution, frozen: MicrophoneSolution,
                       options: CalibrationOptions) -> tuple[Measurements, MicrophoneSolution]:
    """The measurements with the joint fit's cameras and speaker positions, and its
    microphones in the solver's form (so that the result and the report read either)."""
    data = m.data
    solved = np.flatnonzero(np.all(np.isfinite(frozen.positions_m), axis=1))
    poses = [RigPoseInCam0(p.step, p.camera, pose_estimate(bundle, k), p.rms_px)
             for k, p in enumerate(m.speakers.poses)]
    located = [p.locate(data.speakers_rig_m) for p in poses]
    speakers = SpeakerPositions(poses, np.stack([x for x, _ in located]),
                                np.stack([c for _, c in located]), m.speakers.unlocated)
    joint_m = replace(m, cameras=refined_cameras(m.cameras, bundle), speakers=speakers)
    n_mic = len(data.mic_ids)
    positions = np.full((n_mic, 3), np.nan)
    positions[solved] = bundle.state.microphones_m
    covariance = np.full((n_mic, 3, 3), np.nan)
    covariance[solved] = [bundle.marginal("microphones", i, 3) for i in range(solved.size)]
    residuals = np.full(frozen.residuals_s.shape, np.nan)
    residuals[:, solved] = bundle.tof_residuals_s
    outliers = np.zeros(frozen.outliers.shape, dtype=bool)
    outliers[:, solved] = bundle.tof_outliers
    board_column, _ = _latency_layout(data, options)
    solution = MicrophoneSolution(
        positions_m=positions, covariance_m2=covariance,
        speed_of_sound_m_s=bundle.state.speed_of_sound_m_s,
        speed_of_sound_std_m_s=float(bundle.std.speed_of_sound_m_s),
        latency_s=np.append(bundle.state.latencies_s, 0.0)[board_column],
        latency_std_s=np.append(bundle.std.latencies_s, 0.0)[board_column],
        pose_corrections=None, pose_correction_std=None,
        residuals_s=residuals, outliers=outliers,
        sigma_scale=bundle.sigmas.get(GROUP_TOF, float("nan")),
        chi2_per_dof=bundle.chi2_per_dof, nfev=bundle.iterations,
    )  # fmt: skip
    return joint_m, solution


def _per_board(boards: list[str], values: np.ndarray) -> dict[str, float]:
    """Board serial -> value; a single value (no or one common latency) applies to all."""
    values = np.broadcast_to(np.asarray(values, dtype=float), (len(boards),))
    return {b: float(v) for b, v in zip(boards, values, strict=True)}


def _vec(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def _assemble(m: Measurements, sol: MicrophoneSolution, options: CalibrationOptions,
              timings: dict[str, float]) -> CalibrationResult:
    data, cams, speakers, tofs = m.data, m.cameras, m.speakers, m.tofs
    located, reference_fit, reference = m.located, m.reference_fit, m.reference
    boards, _ = board_indices(data)
    residuals = sol.residuals_s
    valid = np.isfinite(residuals) & ~sol.outliers
    mics = _microphone_results(data, sol)
    q_snr = tofs.snr_db[located]
    notes = [CONFOUND_NOTE]
    notes += [f"{m.camera} {m.step}: {m.reason}" for m in cams.missed]
    notes += [f"camera {name} not calibrated: {why}" for name, why in cams.uncalibrated.items()]
    notes += [f"{step}: the board was not found in any calibrated camera; pose skipped"
              for step in speakers.unlocated]
    ref_entry = None
    if reference_fit is not None and reference is not None:
        ref_entry = SpeedOfSoundReference(
            speed_of_sound_m_s=reference_fit.speed_of_sound_m_s,
            speed_of_sound_std_m_s=reference_fit.speed_of_sound_std_m_s, n=reference_fit.n,
            residual_rms_m=reference_fit.residual_rms_m,
            reference_microphone_m=_vec(reference.position_m))
    return CalibrationResult(
        session_id=data.reader.session_id,
        method=options.method,
        microphones=mics,
        speed_of_sound_m_s=sol.speed_of_sound_m_s,
        speed_of_sound_std_m_s=(sol.speed_of_sound_std_m_s if sol.speed_of_sound_std_m_s > 0
                                or reference_fit is None
                                else reference_fit.speed_of_sound_std_m_s),
        speed_of_sound_reference=ref_entry,
        latency_s=_per_board(boards, sol.latency_s),
        latency_std_s=_per_board(boards, sol.latency_std_s),
        cameras=[_camera_result(cams, name) for name in cams.intrinsics],
        poses=[_pose_result(data, speakers, i) for i in range(len(speakers.poses))],
        residuals=ResidualStats(
            rms_s=float(np.sqrt(np.mean(residuals[valid] ** 2))),
            median_abs_s=float(np.median(np.abs(residuals[valid]))),
            n_measurements=int(valid.sum()), n_outliers=int(sol.outliers.sum())),
        tof_quality=TofQuality(
            median_snr_db=float(np.median(q_snr)), p05_snr_db=float(np.percentile(q_snr, 5)),
            median_peak_to_sidelobe_db=float(np.median(tofs.peak_to_sidelobe_db[located])),
            median_predicted_std_s=float(np.median(tofs.std_s[located]))),
        timings_s=dict(timings),
        notes=notes,
        latency_gauge_board=data.config.reference.board,
    )


def _microphone_results(data: SessionData, sol: MicrophoneSolution) -> list[MicrophoneResult]:
    """Every microphone's position, std and residuals in a solution."""
    valid = np.isfinite(sol.residuals_s) & ~sol.outliers
    std = sol.std_m  # NaN where the solver gives no covariance (the paper method)
    mics = []
    for m, mic_id in enumerate(data.mic_ids):
        r = sol.residuals_s[:, m][valid[:, m]]
        mics.append(MicrophoneResult(
            id=int(mic_id), position_m=_vec(sol.positions_m[m]), std_m=_vec(std[m]),
            board=data.mic_boards[m],
            residual_rms_s=float(np.sqrt(np.mean(r**2))) if r.size else float("nan"),
            n_measurements=int(r.size)))
    return mics


def _frozen_summary(m: Measurements, sol: MicrophoneSolution) -> CameraFrozenResult:
    """The camera-frozen solution, for the result beside the joint one."""
    boards, _ = board_indices(m.data)
    intr = m.cameras.intrinsics
    return CameraFrozenResult(
        microphones=_microphone_results(m.data, sol),
        speed_of_sound_m_s=sol.speed_of_sound_m_s,
        speed_of_sound_std_m_s=(sol.speed_of_sound_std_m_s if m.reference_fit is None
                                else m.reference_fit.speed_of_sound_std_m_s),
        latency_s=_per_board(boards, sol.latency_s),
        latency_std_s=_per_board(boards, sol.latency_std_s),
        focal_px={n: (float(c.K[0, 0]), float(c.K[1, 1])) for n, c in intr.items()},
        focal_std_px={n: (float(c.std[0]), float(c.std[1])) for n, c in intr.items()},
    )


def _joint_summary(m: Measurements, bundle: BundleSolution) -> JointFitResult:
    """The joint fit's noise estimates, outliers and convergence, for the result."""
    names = list(m.cameras.intrinsics)
    view_camera = board_views(m.cameras, _bundle_steps(m)[0])[0]
    return JointFitResult(
        sigmas=bundle.sigmas,
        corner_outliers={n: int(bundle.corner_outliers[view_camera == i].sum())
                         for i, n in enumerate(names)},
        tof_outliers=int(bundle.tof_outliers.sum()),
        reference_tof_outliers=int(bundle.reference_outliers.sum()),
        chi2_per_dof=bundle.chi2_per_dof,
        iterations=bundle.iterations,
        reference_microphone_m=_vec(bundle.state.reference_m),
        reference_microphone_std_m=_vec(bundle.std.reference_m),
    )


def _camera_result(cams: CameraCalibration, name: str) -> CameraResult:
    from scipy.spatial.transform import Rotation

    intr = cams.intrinsics[name]
    ext = cams.cam_from_cam0[name]
    missed = [m.step for m in cams.missed if m.camera == name]
    return CameraResult(
        name=name, width=intr.width, height=intr.height, K=intr.K.tolist(),
        dist=intr.dist.ravel().tolist(),
        from_cam0=TransformResult(rotvec=_vec(Rotation.from_matrix(ext.R).as_rotvec()),
                                  t_m=_vec(ext.t)),
        reprojection_rms_px=float(intr.rms_px), images_used=int(intr.n_views),
        images_without_board=missed, intrinsics_std=intr.std.tolist())


def _pose_result(data: SessionData, speakers: SpeakerPositions, i: int) -> PoseResult:
    pose = speakers.poses[i]
    return PoseResult(
        index=int(pose.step.split("/")[1]), step=pose.step, camera=pose.camera,
        rig_to_cam0=TransformResult(rotvec=_vec(pose.rig_to_cam0.rvec),
                                    t_m=_vec(pose.rig_to_cam0.tvec)),
        speakers_m=[_vec(p) for p in speakers.positions_m[i]],
        speakers_std_m=[_vec(np.sqrt(np.diag(c))) for c in speakers.cov_m2[i]],
        reprojection_rms_px=float(pose.rms_px))


__all__ = [
    "CalibrationInputError", "CalibrationOptions", "CalibrationRun", "Measurements", "calibrate",
    "calibrate_measured", "measure", "solve",
]
