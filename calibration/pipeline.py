"""The calibration pipeline: from a capture session to microphone coordinates in the
camera-0 frame (paper sections IV-D to IV-I), one stage after another.

Stages (each timed): cameras (intrinsics, board poses, stereo), speaker positions per pose
(eq. 10) and the reference microphone's position, times of flight, the speed of sound from the
reference microphone (IV-G), the microphone solver (eq. 15; or the paper's own search as a
baseline with `method="paper"`) with the cameras frozen, and last the joint fit
(calibration.solve.bundle): cameras, board poses, microphones, c and latencies refined together,
started from the camera-frozen solution, which is kept and reported beside it.

Choices made here, and why (see docs/calibration.md for the figures behind them):
- latencies: one per board, fitted. The reference microphone records on its own board, so every
  array board's latency is relative to it; they are a few microseconds (0.36 mm of bias per
  microsecond if ignored) and, per board, cheap to fit.
- speed of sound: fixed at the reference-microphone fit when the session has one. That fit
  sees the same camera scale as the speaker positions (so c absorbs a checkerboard or focal
  length scale error, as the paper intends) and is far more precise than the same c fitted
  inside the solver, where it trades off against every microphone's range. The solver's own c
  is still computed and reported beside it. Without that fit (no reference microphone on its
  stand in the pose recordings, or no image of it) a known c (`speed_of_sound_prior`, or the
  session description's measured air) weights the solver's c; with neither, c is solved. The
  result says which (`speed_of_sound_from`). (The joint fit, on by default, fits c itself:
  there the cameras' scale is corrected by the times of flight instead of absorbed by c.)
- joint fit: on by default because, against the simulated truth, it removes the common depth
  offset a frozen camera's focal-length error leaves in the array (0.38 -> 0.01 mm mean error
  on a 30-pose sphere72 session; benchmarks/bench_bundle.py).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from acquisition.contracts.rig_description import KnownIntrinsics
from acquisition.contracts.step_ids import REFMIC_STEP, reference_step
from kernel.air import NOMINAL_SPEED_OF_SOUND_M_S, SpeedOfSoundPrior
from kernel.rigid import RigidTransform

from .solve.bundle import (
    FIXED,
    GROUP_TOF,
    N_INTRINSICS,
    BundlePriors,
    BundleProblem,
    BundleSolution,
    BundleState,
    board_views,
    camera_start,
    fit_bundle,
    pose_estimate,
    refined_cameras,
    view_sigmas,
)
from .camera.camera_calibration import (
    DETECTION_CACHE_SIZE,
    CameraCalibration,
    Checkerboard,
    DetectionMemo,
    calibrate_session,
)
from .checks.capture_checks import (
    CaptureVerdict,
    Wiring,
    apply_verdict,
    check_capture,
    inverted_microphones,
)
from .choices import DEFAULT_LATENCY, LatencyModel, Stage
from .acoustic.delay_estimation import Weighting
from .checks.distortion import ReferenceFloors, reference_floors
from .errors import CalibrationInputError
from .checks.fit_checks import (
    GROSS_SHARE,
    SWAP_SCATTER,
    SourceResiduals,
    SpeakerSwap,
    moved_poses,
    on_lent_reference,
    reference_offset,
    speaker_findings,
)
from .camera.image_checks import ImageCheckMemo
from .checks.layout_check import NominalLayout, check_layout, relabelled
from .memo import LruMemo
from .solve.multilateration import multilaterate
from .solve.paper_method import solve_paper_method
from .plan import (
    _bundle_steps,
    board_indices,
    known_intrinsics,
    known_speed_of_sound,
    speed_of_sound_plan,
)
from .checks.plausibility import (
    AIR_RANGE_M_S,
    FitFigures,
    acoustic_problems,
    optical_problems,
    raise_if_implausible,
    turned_rig,
)
from .checks.response_checks import close_reflections
from .acoustic.responses import (
    THIRD_OCTAVE_CENTRES_HZ,
    Flights,
    MicrophoneResponses,
    dispersion_centres_hz,
    dispersion_delays,
    estimate_responses,
    evenly_spread,
)
from .result import CalibrationResult, Finding
from .result_assembly import (
    _assemble,
    _frozen_summary,
    _joint_summary,
    _responses_result,
    _rig_summary,
    _with_delays,
)
from .session_data import SessionData, load_session
from .solve.acoustic_pose import place_rig
from .solve.solver import (
    MicrophoneSolution,
    PriorGeometry,
    RigSources,
    SolverOptions,
    latency_columns,
    solve_microphones,
)
from .camera.recovered_views import recover_views, recovery_note, with_recovery
from .camera.speakers import (
    ReferenceMicrophonePosition,
    RigPoseInCam0,
    SpeakerLocationError,
    SpeakerPositions,
    reference_microphone_position,
    speaker_positions,
)
from .acoustic.speed_of_sound import SpeedOfSoundFit, fit_speed_of_sound_robust
from .acoustic.times_of_flight import (
    TOF_CACHE_POSES,
    SessionTofs,
    TofMemo,
    measure_session_tofs,
    recording_hashes,
)

FREE_FIELD_ECHO_RATIO = 1.02
"""The largest echo ratio (`SessionTofs.echo_ratio`: the correlations' energy in the 20 ms
after the direct sound over that in the 20 ms before it, pooled over the session) at which
weighting "auto" takes the matched weighting. In free field with flat capsules the ratio
is 1 up to its statistical spread, a few thousandths over a session of thousands of
measurements (the simulated ideal world, five 20-pose sessions: 0.999-1.004); in the
realistic lab, whose room reflects, it is about 5000.
A reflection's share of the ratio grows with the square of the bias it gives a matched
delay in units of that delay's noise: at 1.02, one in every measurement 0.2 ms behind the
direct sound (a table) is seen from about a quarter of the noise on, later ones sooner.
A small session's ratio spreads more, and above 1.02 it falls back to compact, the safe
side."""
OFF_AXIS_STD_M = 1e-3
"""Prior standard deviation of b, how far the speakers' acoustic centre moves forward off
axis (calibration.solve.bundle): a small driver's centre moves with frequency by tenths of a
millimetre per octave, and what a correlation sees of it off axis by a fraction of that
(85 um in the simulated lab); 1 mm leaves it to the data without letting it trade freely
against the latencies when the poses are few."""

JOINT_NOTE = (
    "Final fit: the optical-acoustic bundle adjustment (cameras, board poses, microphones, c "
    "and latencies fitted to the corner pixels and the times of flight together); the "
    "camera-frozen solution it started from is under camera_frozen. Gauges: the camera-0 "
    "frame, the checkerboard's printed scale, latency 0 for the reference microphone's board."
)


REFERENCE_FLOORS_SESSIONS = 64
"""Sets of reference recordings whose distortion floors a `WorkMemo` remembers (12 numbers
each)."""


@dataclass(frozen=True)
class WorkMemo:
    """The work a long-running caller remembers between calibrations, by the content of the
    files it was done on: checkerboard detections and image checks per image, delays per
    pose, the reference recordings' distortion floors per session.

    Its owner answers for the files it remembers, which are not read again: the worker
    verifies every file of its session copies against the journal when it fetches it. A
    caller without one (`micam calibrate`, a script) reads and checks every file."""

    detections: DetectionMemo = field(default_factory=lambda: DetectionMemo(DETECTION_CACHE_SIZE))
    tofs: TofMemo = field(default_factory=lambda: TofMemo(TOF_CACHE_POSES))
    image_checks: ImageCheckMemo = field(
        default_factory=lambda: ImageCheckMemo(DETECTION_CACHE_SIZE))
    reference_floors: LruMemo[tuple[str, ...], ReferenceFloors] = field(
        default_factory=lambda: LruMemo(REFERENCE_FLOORS_SESSIONS))


@dataclass(frozen=True)
class CalibrationOptions:
    """Options of `calibrate`.

    Attributes:
        method: "micam" (the sparse robust solver) or "paper" (section IV-I's coordinate search
            from zeros, c fixed, no latency; the baseline).
        latency: "per_board" (the default, `calibration.choices.DEFAULT_LATENCY`), "common" or
            "none".
        speed_of_sound: "reference" (fixed at the reference-microphone fit; falls back to
            "solve" without a refmic image) or "solve" (an unknown of the solver).
        refine_poses: fit a rigid correction per rig pose, weighted by the camera's pose
            covariance.
        band_hz: the band the times of flight are estimated in (the speaker band).
        weighting: the correlations' spectral weighting (calibration.acoustic.delay_estimation):
            "compact" (robust to early reflections), "matched" (maximum likelihood in free
            field), "phat", or "auto" (the default): compact, unless the recordings hold
            nothing but the direct sound and noise (`FREE_FIELD_ECHO_RATIO`; an anechoic
            room and flat capsules), where matched is as unbiased and about 1.2x more
            precise.
        allow_interrupted: calibrate the completed poses of an interrupted session.
        joint: finish with the optical-acoustic bundle adjustment (method "micam" only); the
            camera-frozen solution is reported beside it.
        prior: a known geometry of the array in its own frame (CAD or an earlier
            calibration), in the session's microphone order: the solver then fits its rigid
            transform R_m, T_m into the camera-0 frame (paper IV-H), and each microphone's
            deviation from it if the prior has a deviation std. Method "micam" only. It is
            also the layout the geometry is checked against, unless `layout` is given.
        layout: the array's nominal layout, by microphone id: the geometry, solved free of
            any prior, is compared with it, and swapped microphone cables or a column map
            off by whole boards are relabelled (calibration.checks.layout_check); None (and no
            prior): the layout of the session's description, if it has one (the options'
            replace it, and the result's notes say so).
        layout_tolerance_m: how far (m) a microphone may lie from its nominal place, for
            whichever layout is used; None: that layout's own.
        described_layout: False: the session description's layout is not used (a layout
            check only with `layout` or `prior`; a benchmark's "without a layout").
        speaker_offsets: the joint fit estimates where each speaker's sound comes from on the
            rig (its offset from the stated position, held to the rig's stated tolerance in
            the board plane and to its acoustic-centre prior along the normal, and how far
            the acoustic centre moves forward off axis).
        print_scale: the joint fit estimates the printed pattern's scale (held to the rig's
            stated print tolerance).
        mic_delay_std_s: the joint fit estimates each microphone's own delay (capsule and
            channel group delay) with this prior standard deviation; None: no such unknown.
        speed_of_sound_per_pose: the joint fit estimates c per pose (the air drifting),
            consecutive poses' c held together by `speed_of_sound_step_m_s`.
        speed_of_sound_step_m_s: standard deviation of c's change from pose to pose.
        speed_of_sound_prior: (c, std) in m/s, a known speed of sound (a measured air
            temperature or c); it replaces the session description's `air` and the session's
            air-sensor readings. The joint fit takes it as a prior on the session's mean c;
            the camera-frozen solver holds its c to it (fixed if the std is 0) when the
            session has no reference-microphone fit.
        intrinsics: camera calibrations known from elsewhere, by camera name ("fixed" or a
            "prior"); they replace the session description's.
        responses: estimate every microphone's complex response against frequency after the
            joint fit (calibration.acoustic.responses).
        air_sensor: use the session's air-sensor readings as the known speed of sound (when
            neither the options nor the description give one).
        dispersion: with `responses`, take every microphone's measured dispersion (its phase
            less a delay) out of its times of flight and fit again (calibration.acoustic.responses).
        memo: the caller's memo of the work done per file (a worker keeps one across its
            jobs, see `WorkMemo`); None: nothing is remembered, every file is read.
    """

    method: Literal["micam", "paper"] = "micam"
    latency: LatencyModel = DEFAULT_LATENCY
    speed_of_sound: Literal["reference", "solve"] = "reference"
    refine_poses: bool = False
    band_hz: tuple[float, float] = (300.0, 20_000.0)
    weighting: Literal["auto"] | Weighting = "auto"
    allow_interrupted: bool = False
    joint: bool = True
    prior: PriorGeometry | None = None
    layout: NominalLayout | None = None
    layout_tolerance_m: float | None = None
    described_layout: bool = True
    speaker_offsets: bool = True
    print_scale: bool = True
    mic_delay_std_s: float | None = 1e-6
    speed_of_sound_per_pose: bool = True
    speed_of_sound_step_m_s: float = 0.01
    speed_of_sound_prior: SpeedOfSoundPrior | None = None
    intrinsics: dict[str, KnownIntrinsics] | None = None
    responses: bool = True
    air_sensor: bool = True
    dispersion: bool = True
    memo: WorkMemo | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class LentReference:
    """How a speaker with a spoiled reference recording was measured.

    Attributes:
        lender: the speaker whose reference recording its bursts were correlated with.
        shift_s: taken out of its times of flight before the fits: its median residual on
            the camera-frozen solution, relative to the other speakers' (its emission delay
            after the lender's, to the joint fit's refinement).
    """

    lender: int
    shift_s: float


@dataclass
class Measurements:
    """Everything the solver works from: the session, the cameras, the speaker positions,
    the times of flight, the reference-microphone fit of c and (`air`) the (c, std) in m/s
    that the session's air-sensor readings imply (their mean c; the std is the sensor's
    stated accuracy, systematic, so not reduced by the number of readings), and (`weighting`)
    the spectral weighting the times of flight were correlated with."""

    data: SessionData
    cameras: CameraCalibration
    speakers: SpeakerPositions
    located: list[int]
    tofs: SessionTofs
    reference: ReferenceMicrophonePosition | None
    reference_fit: SpeedOfSoundFit | None
    timings_s: dict[str, float] = field(default_factory=dict)
    air: SpeedOfSoundPrior | None = None
    notes: list[str] = field(default_factory=list)
    weighting: Weighting = "compact"
    findings: list[Finding] = field(default_factory=list)
    kept_microphones: np.ndarray | None = None
    reference_levels_db: np.ndarray | None = None
    """(S,) each speaker's reference recording's level over the median speaker's, dB
    (calibration.checks.distortion.ReferenceFloors): a reference microphone further than
    stated hears its speaker weaker (calibration.checks.fit_checks.reference_offset)."""
    lent_references: dict[int, LentReference] = field(default_factory=dict)
    """The speakers measured on another's reference recording, their own being spoiled
    (`_on_lent_reference`); the joint fit gives each an emission delay of its own."""


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


def _timed(timings: dict[str, float], name: Stage, on_stage: Callable[[str], None] | None):
    """Context manager that tells `on_stage` and adds the stage's duration in seconds to
    `timings` (a stage may run twice: the solver after placing unseen poses, the dispersion
    and the joint fit for speakers on a lent reference recording)."""

    class _Stage:
        def __enter__(self) -> None:
            if on_stage is not None:
                on_stage(name)
            self.t0 = time.perf_counter()

        def __exit__(self, *exc: object) -> None:
            elapsed = time.perf_counter() - self.t0
            timings[name] = round(timings.get(name, 0.0) + elapsed, 3)

    return _Stage()


def measure(path: Path, options: CalibrationOptions | None = None,
            on_stage: Callable[[str], None] | None = None) -> Measurements:
    """Every measurement of a session: cameras, speaker positions, times of flight, and the
    speed of sound from the reference microphone (when the session has its image)."""
    options = options or CalibrationOptions()
    timings: dict[str, float] = {}
    with _timed(timings, "load", on_stage):
        data = load_session(path, options.allow_interrupted)
    memo = options.memo
    with _timed(timings, "cameras", on_stage):
        cams = calibrate_session(data.reader, Checkerboard.of_rig(data.rig),
                                 list(data.camera_names), known_intrinsics(data, options),
                                 detections=None if memo is None else memo.detections,
                                 image_checks=None if memo is None else memo.image_checks)
    with _timed(timings, "speakers", on_stage):
        speakers = speaker_positions(cams, data.speakers_rig_m, data.pose_steps)
        reference = _reference_position(cams, data)
    with _timed(timings, "times of flight", on_stage):
        floors = _reference_floors(data, options.memo)
        tofs, weighting, verdict = _times_of_flight(data, options, floors)
    session_mics = data.mic_ids.size
    data, tofs = apply_verdict(data, tofs, verdict)
    located = [data.pose_steps.index(p.step) for p in speakers.poses]
    reference_fit, notes = _reference_fit(speakers, reference, tofs.reference_tof_s[located])
    kept = None if verdict.kept.size == session_mics else verdict.kept
    return Measurements(data, cams, speakers, located, tofs, reference, reference_fit, timings,
                        _air(data), notes, weighting, [*cams.findings, *verdict.findings],
                        kept, floors.level_db)


def _times_of_flight(data: SessionData, options: CalibrationOptions, floors: ReferenceFloors
                     ) -> tuple[SessionTofs, Weighting, CaptureVerdict]:
    """The session's times of flight, the weighting they were correlated with and the
    capture's mistakes they (and the reference recordings' `floors`) show.

    The weighting is the options', or for "auto" compact, then matched where the echo ratio
    shows free field (`FREE_FIELD_ECHO_RATIO`; a second pass over the recordings). The
    matched pass's impulses replace the compact ones too: the capsules' dispersion that the
    times of flight are corrected for must be weighted as the correlations that measured
    them were (calibration.acoustic.responses.dispersion_delays), and the responses relative to the
    array do not depend on the weighting. Microphones wired inverted are found in the first
    pass and correlated with the opposite sign from then on (one more pass)."""
    memo = None if options.memo is None else options.memo.tofs
    first: Weighting = "compact" if options.weighting == "auto" else options.weighting

    def correlated(weighting: Weighting, polarity: np.ndarray | None = None) -> SessionTofs:
        return measure_session_tofs(data, NOMINAL_SPEED_OF_SOUND_M_S, options.band_hz,
                                    weighting, memo=memo, polarity=polarity)

    tofs = uncorrected = correlated(first)
    inverted = inverted_microphones(tofs)
    if inverted.size:
        polarity = np.ones(data.mic_ids.size)
        polarity[inverted] = -1.0
        tofs = correlated(first, polarity)
    weighting = first
    if options.weighting == "auto" and tofs.echo_ratio() <= FREE_FIELD_ECHO_RATIO:
        # (a NaN ratio, nothing to judge by, keeps compact too)
        tofs, weighting = correlated("matched", tofs.polarity), "matched"
    verdict = check_capture(data, tofs, uncorrected if inverted.size else None, floors)
    return tofs, weighting, verdict


def _reference_floors(data: SessionData, memo: WorkMemo | None) -> ReferenceFloors:
    """The distortion floors of the session's reference recordings, remembered by their
    SHA-256 in `memo` (a worker's live jobs see the same references with every pose)."""
    key = recording_hashes(data, reference_step)
    if memo is not None and (known := memo.reference_floors.get(key)) is not None:
        return known
    floors = reference_floors(data.references(), data.description.burst, data.fs)
    if memo is not None:
        memo.reference_floors.put(key, floors)
    return floors


def _reference_fit(speakers: SpeakerPositions, reference: ReferenceMicrophonePosition | None,
                   tofs_s: np.ndarray) -> tuple[SpeedOfSoundFit | None, list[str]]:
    """The paper's IV-G fit of c (robust), or None with a note when it is not air's."""
    if reference is None:
        return None, []
    distances = np.linalg.norm(speakers.positions_m - reference.position_m, axis=2)
    try:
        fit = fit_speed_of_sound_robust(distances.ravel(), tofs_s.ravel())
    except ValueError:
        fit = None
    lo, hi = AIR_RANGE_M_S
    if fit is None or not lo <= fit.speed_of_sound_m_s <= hi:
        found = "no fit" if fit is None else f"{fit.speed_of_sound_m_s:.1f} m/s"
        return None, [f"the reference microphone on its stand gave no speed of sound that air "
                      f"can have ({found}): not used; does every speaker face it?"]
    return fit, []


def _air(data: SessionData) -> SpeedOfSoundPrior | None:
    """(c, std) from the air sensor's readings of the session, None without any."""
    readings = list(data.air_readings().values())
    if not readings:
        return None
    implied = np.array([r.speed_of_sound() for r in readings])
    return SpeedOfSoundPrior(float(np.mean(implied[:, 0])), float(np.mean(implied[:, 1])))


def calibrate(path: Path, options: CalibrationOptions | None = None,
              on_stage: Callable[[str], None] | None = None) -> CalibrationRun:
    """Calibrate the session at `path`. `on_stage` is told the name of each stage as it starts.

    Raises CalibrationInputError (or the cameras' and speakers' own errors, all ValueError)
    with a message that says what is missing; ImplausibleCalibrationError (a
    CalibrationInputError) when the result's own figures say its model is wrong
    (calibration.checks.plausibility), naming the likely cause.
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
    layout, session_prior = _nominal_layout(m, options), options.prior
    m = replace(m, notes=[*m.notes, *_layout_notes(m, options)])
    options = _for_kept_microphones(options, m.kept_microphones)
    timings = dict(m.timings_s)
    with _timed(timings, "solver", on_stage):
        m, options, solution = _solve_checked(m, options, poses, layout, session_prior)
    _check_plausible(m, options, _solution_figures(m, solution, options), frozen=True)
    if not (options.joint and options.method == "micam"):
        return CalibrationRun(_assemble(m, solution, options, timings), m, solution)
    if poses is None and (placed := _placed_by_their_bursts(m, solution)) is not m:
        m = placed
        with _timed(timings, "solver", on_stage):
            solution = solve(m, options)
    undispersed = m
    dispersion = options.responses and options.dispersion
    if dispersion:
        with _timed(timings, "dispersion", on_stage):
            m = _without_dispersion(m, _frozen_responses(m, solution, options))
    with _timed(timings, "joint fit", on_stage):
        bundle = fit_joint(m, solution, options, poses)
    if dispersion and m.lent_references:
        # their impulses lay off by their emission delays, which the joint fit now knows
        with _timed(timings, "dispersion", on_stage):
            undispersed = _emission_aligned(undispersed, bundle)
            m = _without_dispersion(undispersed, _frozen_responses(undispersed, solution,
                                                                   options))
        with _timed(timings, "joint fit", on_stage):
            bundle = fit_joint(m, solution, options, poses, start=bundle.state)
    joint_m, joint_solution = joint_measurements(m, bundle, solution, options)
    names = list(m.cameras.intrinsics)
    _check_plausible(m, options, replace(
        _solution_figures(m, joint_solution, options),
        corner_rms_px={n: float(bundle.corner_rms_px[i]) for i, n in enumerate(names)}))
    responses = None
    if options.responses:
        with _timed(timings, "responses", on_stage):
            est = _responses(m, lambda k: joint_flights(m, bundle, solution, k),
                             bundle.state.speed_of_sound_m_s)
            responses = _responses_result(m, est)
    result = _assemble(joint_m, joint_solution, options, timings)
    result = result.model_copy(update={
        "microphones": _with_delays(result.microphones, bundle, solution),
        "camera_frozen": _frozen_summary(m, solution, options),
        "speed_of_sound_from": "joint_fit",
        "joint_fit": _joint_summary(m, bundle, options),
        "rig": _rig_summary(m, bundle),
        "microphone_responses": responses,
        "notes": [*result.notes, JOINT_NOTE],
    })
    result = result.model_copy(update={
        "findings": [*result.findings, *close_reflections(result, Wiring(m.data))]})
    return CalibrationRun(result, joint_m, joint_solution, solution, bundle)


PLACED_BY_TIMES_OF_FLIGHT = "times of flight"
"""`RigPoseInCam0.camera` of a pose that no camera located and its bursts placed."""


def _placed_by_their_bursts(m: Measurements, solution: MicrophoneSolution) -> Measurements:
    """The measurements with every pose step that no camera located (its board not found, or
    its views left out) placed by its own times of flight (calibration.solve.acoustic_pose),
    from the camera-frozen `solution`'s microphones, latencies and c, with a note for each;
    `m` itself when there is none to place. The joint fit then holds such a pose by its times
    of flight alone: its bursts are kept, and of its images the corners that can be found
    again where that pose puts them (calibration.camera.recovered_views)."""
    located = set(m.located)
    # the speakers the checks left out at every located pose (a swap, a misplaced reference
    # microphone) are left out of the placed poses too
    left_out = ~np.isfinite(m.tofs.tof_s[m.located]).any(axis=(0, 2))
    tof, std = m.tofs.tof_s.copy(), m.tofs.std_s.copy()
    _, board_of_mic = board_indices(m.data)
    latency = solution.latency_s[board_of_mic]
    kept = np.isfinite(solution.residuals_s) & ~solution.outliers
    if not kept.any():
        return m
    typical = float(np.median(np.abs(solution.residuals_s[kept])))
    starts = [p.rig_to_cam0.transform for p in m.speakers.poses]
    placed: dict[int, RigPoseInCam0] = {}
    notes = []
    for row, step in enumerate(m.data.pose_steps):
        if row in located:
            continue
        tof[row, left_out] = std[row, left_out] = np.nan
        pose = place_rig(tof[row], solution.positions_m, latency,
                         solution.speed_of_sound_m_s, m.data.speakers_rig_m, starts, typical)
        if pose is None:
            continue
        placed[row] = RigPoseInCam0(step, PLACED_BY_TIMES_OF_FLIGHT, pose, np.nan)
        notes.append(f"{step}: no camera located the rig; its own times of flight placed it, "
                     "and its bursts were used (its images were not)")
    if not placed:
        return m
    cameras, recovered = recover_views(m.cameras, m.data.reader, {
        p.step: p.rig_to_cam0.transform for p in placed.values()})
    notes += [recovery_note(key, found, cameras.board.n_corners)
              for key, found in recovered.items()]
    by_row = {**dict(zip(m.located, m.speakers.poses, strict=True)), **placed}
    rows = sorted(by_row)
    poses = [by_row[r] for r in rows]
    where = [p.locate(m.data.speakers_rig_m) for p in poses]
    speakers = SpeakerPositions(poses, np.stack([x for x, _ in where]),
                                np.stack([c for _, c in where]),
                                [s for s in m.speakers.unlocated
                                 if s not in {p.step for p in placed.values()}])
    return replace(m, speakers=speakers, located=rows, notes=[*m.notes, *notes],
                   tofs=replace(m.tofs, tof_s=tof, std_s=std), cameras=cameras,
                   findings=[with_recovery(f, recovered) for f in m.findings])


def _session_ids(data: SessionData) -> np.ndarray:
    """Every microphone id of the session (those left out too), in its column order."""
    return np.array([i for i, _, _ in data.description.microphones()])


def _nominal_layout(m: Measurements, options: CalibrationOptions) -> NominalLayout | None:
    """The layout the geometry is checked against: the options', else the prior's (which is
    given in the session's microphone order), else the session description's; None without
    any."""
    described = m.data.description.layout
    if options.layout is not None:
        layout: NominalLayout | None = options.layout
    elif options.prior is not None:
        layout = NominalLayout(_session_ids(m.data), options.prior.positions_m)
    else:
        layout = (None if described is None or not options.described_layout
                  else NominalLayout.described(described))
    if layout is None or options.layout_tolerance_m is None:
        return layout
    return replace(layout, tolerance_m=options.layout_tolerance_m)


def _layout_notes(m: Measurements, options: CalibrationOptions) -> list[str]:
    """Which layout the wiring is checked against, when the session's description has one:
    its own, or (said, so that nobody wonders why it was not used) the options'."""
    described = m.data.description.layout
    if described is None or not options.described_layout:
        return []
    source = f" ({described.source})" if described.source else ""
    if options.layout is None and options.prior is None:
        return [f"wiring checked against the array's nominal layout in the session's "
                f"description{source}"]
    given = "layout" if options.layout is not None else "prior geometry"
    return [f"wiring checked against the {given} given in the options, which replaces the "
            f"nominal layout in the session's description{source}"]


def _solve_checked(m: Measurements, options: CalibrationOptions, poses: np.ndarray | None,
                   layout: NominalLayout | None, session_prior: PriorGeometry | None
                   ) -> tuple[Measurements, CalibrationOptions, MicrophoneSolution]:
    """The camera-frozen solution without misfits (`_without_misfits`), its microphones
    checked against `layout` when there is one: the check looks at a solution free of the
    prior (which would hold swapped microphones to the wrong places), then the columns are
    relabelled as the check says and the prior (`session_prior`, in the session's order)
    follows the new ids. An implausible free solution is refused before the check
    (`_check_plausible`). The measurements carry the check's findings, and the earlier
    findings name the microphones by their new ids."""
    free = replace(options, prior=None)
    solution = solve(m, free, poses)
    m, solution = _without_misfits(m, free, poses, solution)
    if layout is None:
        return m, options, solution
    # a geometry whose model is wrong (a turned pattern, a wrong sample rate) fits no layout:
    # say what is wrong with it, not that the layout does not fit
    _check_plausible(m, free, _solution_figures(m, solution, free), frozen=True)
    verdict = check_layout(m.data, solution.positions_m, layout)
    earlier = [relabelled(f, verdict.renamed) for f in m.findings]
    m = replace(m, data=replace(m.data, mic_ids=verdict.ids),
                findings=[*earlier, *verdict.findings])
    if session_prior is None:
        return m, options, solution
    index = {int(i): k for k, i in enumerate(_session_ids(m.data))}
    rows = [index[int(i)] for i in verdict.ids]
    options = replace(options, prior=replace(session_prior,
                                             positions_m=session_prior.positions_m[rows]))
    return m, options, solve(m, options, poses)


def _without_misfits(m: Measurements, options: CalibrationOptions, poses: np.ndarray | None,
                     solution: MicrophoneSolution) -> tuple[Measurements, MicrophoneSolution]:
    """The measurements and the camera-frozen solution without the speakers and poses whose
    times of flight do not fit the geometry of the others (calibration.checks.fit_checks: swapped
    speaker cables, a reference microphone at another distance than stated, a rig moved
    after its images), with findings that name them. A swap and a misplaced reference
    microphone spoil only the speakers' reference recordings: their bursts are kept,
    correlated with a sound speaker's (`_on_lent_reference`), when they then fit."""
    rows = np.asarray(m.located)[np.arange(len(m.located)) if poses is None else poses]
    shape = (rows.size, m.data.n_speakers)

    def with_tofs(tof_s: np.ndarray, std_s: np.ndarray) -> Measurements:
        tof, std = m.tofs.tof_s.copy(), m.tofs.std_s.copy()
        tof[rows], std[rows] = tof_s, std_s
        return replace(m, tofs=replace(m.tofs, tof_s=tof, std_s=std))

    def residuals_of(tof_s: np.ndarray, std_s: np.ndarray) -> SourceResiduals:
        return SourceResiduals.of(solve(with_tofs(tof_s, std_s), options, poses), *shape)

    tof, std = m.tofs.tof_s[rows].copy(), m.tofs.std_s[rows].copy()
    residuals = SourceResiduals.of(solution, *shape)
    findings, speakers, swap = speaker_findings(
        tof, std, residuals, lambda t, s: solve(with_tofs(t, s), options, poses))
    used = np.ones(m.data.n_speakers, dtype=bool)
    if swap is not None and (lent := _on_lent_reference(m, options, poses, residuals,
                                                        swap, used)) is not None:
        m, residuals, lender = lent
        findings = [on_lent_reference(findings[0], lender)]
        speakers = np.array([], dtype=int)
        used[list(swap.speakers)] = False  # their offset is fitted: nothing to judge by it
        tof, std = m.tofs.tof_s[rows].copy(), m.tofs.std_s[rows].copy()
    if speakers.size:
        tof[:, speakers] = std[:, speakers] = np.nan
        residuals = residuals_of(tof, std)
    used[speakers] = False
    while (offset := reference_offset(residuals, solution.speed_of_sound_m_s,
                                      m.data.reference_distances_m, used,
                                      m.reference_levels_db)) is not None:
        finding, k = offset
        used[k] = False
        lent = _on_lent_reference(m, options, poses, residuals, k, used)
        if lent is None:
            tof[:, k] = std[:, k] = np.nan
            findings.append(finding)
            residuals = residuals_of(tof, std)
            continue
        m, residuals, lender = lent
        findings.append(on_lent_reference(finding, lender))
        left_out = np.isnan(tof)
        tof, std = m.tofs.tof_s[rows].copy(), m.tofs.std_s[rows].copy()
        tof[left_out] = std[left_out] = np.nan

    def without_poses(moved: list[int]) -> SourceResiduals:
        t, s = tof.copy(), std.copy()
        t[moved] = s[moved] = np.nan
        return residuals_of(t, s)

    steps = [m.data.pose_steps[r] for r in rows]
    pose_findings, moved = moved_poses(residuals, steps, without_poses)
    if not findings and not pose_findings:
        return m, solution
    tof[moved] = std[moved] = np.nan
    checked = replace(with_tofs(tof, std), findings=[*m.findings, *findings, *pose_findings])
    spoiled = [k for f in findings if f.action == "left out" and f.kind in (
        "misplaced-reference-microphone", "swapped-speakers") for k in f.speakers]
    if spoiled:  # the stand's reference microphone was correlated with those templates too
        reference = checked.tofs.reference_tof_s.copy()
        reference[:, spoiled] = np.nan
        checked = replace(checked, tofs=replace(checked.tofs, reference_tof_s=reference))
    return checked, solve(checked, options, poses)


LENT_EMISSION_STD_S = 1e-4
"""Prior standard deviation of the emission delay of a speaker measured on another
speaker's reference recording (`Measurements.lent_references`): wide, so that the data
decide it (drivers and amplifiers of one kind differ by microseconds, cables by less)."""


def _on_lent_reference(m: Measurements, options: CalibrationOptions, poses: np.ndarray | None,
                       residuals: SourceResiduals, spoiled: SpeakerSwap | int, used: np.ndarray
                       ) -> tuple[Measurements, SourceResiduals, int] | None:
    """The measurements with a spoiled speaker's bursts (`spoiled`: one whose reference
    microphone was misplaced, or a swap, whose recordings are exchanged too) correlated
    again with the reference recording of the sound speaker that fits best (the `used`
    speaker whose residuals' median is nearest the others'), their times of flight shifted
    by their median residual (the emission delay, fitted again in the joint fit), and the
    solution's residuals; None when no sound speaker is left to lend its recording, or when
    the bursts do not fit then (`SWAP_SCATTER`, `GROSS_SHARE`): the caller leaves them out.

    Why this is safe: every speaker plays the same burst through the same kind of driver,
    so another speaker's reference recording is its own but for a constant delay. On the
    20-pose realistic sessions, a swapped speaker measured on a lent recording lies within
    1 ns (median) of the same speaker measured on its own in the session without the swap.
    """
    heard = [spoiled] if isinstance(spoiled, int) else list(spoiled.heard)
    moved = heard if isinstance(spoiled, int) else [
        spoiled.speakers[1] if k == spoiled.speakers[0] else spoiled.speakers[0] for k in heard]
    involved = set(heard) | set(moved)
    with warnings.catch_warnings():  # a speaker left out has no residual: NaN, as it says
        warnings.simplefilter("ignore", RuntimeWarning)
        offset_s = np.nanmedian(residuals.residual_s, axis=(0, 2))
    lenders = np.flatnonzero(used & np.isfinite(offset_s)
                             & ~np.isin(np.arange(used.size), list(involved)))
    if lenders.size == 0:
        return None
    lender = int(lenders[np.argmin(np.abs(offset_s[lenders] - np.median(offset_s[lenders])))])
    templates = np.arange(m.data.n_speakers)
    templates[heard] = lender
    again = measure_session_tofs(m.data, NOMINAL_SPEED_OF_SOUND_M_S, options.band_hz,
                                 m.weighting, memo=None if options.memo is None
                                 else options.memo.tofs, polarity=m.tofs.polarity,
                                 templates=templates)
    tofs = m.tofs.with_speakers_from(again, heard)
    if not isinstance(spoiled, int):
        tofs = tofs.exchanged(*spoiled.speakers)
    levels = m.reference_levels_db
    if levels is not None:
        levels = levels.copy()
        levels[moved] = levels[lender]
    trial = replace(m, tofs=tofs, reference_levels_db=levels)
    shape = residuals.residual_s.shape[:2]
    fitted = SourceResiduals.of(solve(trial, options, poses), *shape)
    scatter = fitted.speaker_scatter_us()
    others = np.flatnonzero(used & np.isfinite(scatter)
                            & ~np.isin(np.arange(used.size), list(involved)))
    if others.size == 0:
        return None
    typical = float(np.median(scatter[others]))
    if not (np.all(scatter[moved] < SWAP_SCATTER * max(typical, 1e-3))
            and np.all(fitted.outlier_share((0, 2))[moved] <= GROSS_SHARE)):
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        offset_s = np.nanmedian(fitted.residual_s, axis=(0, 2))
    shift = offset_s[moved] - np.median(offset_s[others])
    shifted = replace(trial.tofs, tof_s=trial.tofs.tof_s.copy(),
                      reference_tof_s=trial.tofs.reference_tof_s.copy())
    shifted.tof_s[:, moved] -= shift[None, :, None]
    shifted.reference_tof_s[:, moved] -= shift[None, :]
    lent = {k: LentReference(lender, float(s)) for k, s in zip(moved, shift, strict=True)}
    trial = replace(trial, tofs=shifted, lent_references={**m.lent_references, **lent})
    return trial, SourceResiduals.of(solve(trial, options, poses), *shape), lender


def _for_kept_microphones(options: CalibrationOptions, kept: np.ndarray | None
                          ) -> CalibrationOptions:
    """`options` for the microphones `kept` of the session (None: all of them): a prior
    geometry, given in the session's microphone order, without the others."""
    if kept is None or options.prior is None:
        return options
    return replace(options, prior=replace(options.prior,
                                          positions_m=options.prior.positions_m[kept]))


def _solution_figures(m: Measurements, sol: MicrophoneSolution,
                      options: CalibrationOptions) -> FitFigures:
    return FitFigures(sol.speed_of_sound_m_s, sol.speed_of_sound_std_m_s, sol.residuals_s,
                      sol.outliers, {}, known_speed_of_sound(m, options))


def _check_plausible(m: Measurements, options: CalibrationOptions, fig: FitFigures,
                     frozen: bool = False) -> None:
    """Raise ImplausibleCalibrationError if the solution's figures say its model is wrong
    (`frozen`: the camera-frozen solution, whose c is held and whose residuals still carry
    the cameras' errors: only grossly misfitting times of flight count); when the times of
    flight fit with the rig turned by 180 degrees, say so."""
    acoustic = acoustic_problems(fig, frozen)
    problems = acoustic + ([] if frozen else optical_problems(fig))
    cause = _turned_rig_fits(m, options) if acoustic else None
    raise_if_implausible(problems, cause)


def _turned_rig_fits(m: Measurements, options: CalibrationOptions) -> str | None:
    """The likely cause when the camera-frozen solver fits the session with the rig's
    pattern origin at the opposite corner (speakers 1-4, 2-3, 5-6 swapped), else None."""
    data = m.data
    rig = data.rig
    turned = turned_rig(data.speakers_rig_m, rig.corners_x, rig.corners_y, rig.square_m)
    rig_t = rig.model_copy(update={"speakers_m": tuple(tuple(float(v) for v in p)
                                                       for p in turned)})
    data_t = replace(data, description=data.description.model_copy(update={"rig": rig_t}))
    speakers = speaker_positions(m.cameras, data_t.speakers_rig_m, data.pose_steps)
    fit = None
    if m.reference is not None and data.reference_column is not None:
        fit, _ = _reference_fit(speakers, m.reference, m.tofs.reference_tof_s[m.located])
    m_t = replace(m, data=data_t, speakers=speakers, reference_fit=fit)
    try:
        sol = solve(m_t, options)
    except ValueError:
        return None
    if acoustic_problems(_solution_figures(m_t, sol, options), frozen=True):
        return None
    return ("the times of flight fit with the rig turned by 180 degrees in its plane (speakers "
            "1-4, 2-3 and 5-6 swapped): the checkerboard's origin is at the other end of the "
            "pattern from where the description puts it, i.e. its colour convention "
            "(rig.origin_square: the colour of the square at the origin) or its corner order "
            "is the opposite one; correct the rig description and calibrate again")


def _reference_position(cams: CameraCalibration,
                        data: SessionData) -> ReferenceMicrophonePosition | None:
    """The reference microphone on its stand, when the pose recordings hold it and the
    session has its image (and the rig its reference mark); otherwise None."""
    mark = data.rig.reference_mark_m
    if data.reference_column is None or mark is None or REFMIC_STEP not in data.reader.steps():
        return None
    try:
        return reference_microphone_position(cams, np.array(mark))
    except SpeakerLocationError:
        return None


def _rig_sources(data: SessionData, speakers: SpeakerPositions, pose_idx: np.ndarray,
                 spk_idx: np.ndarray) -> RigSources:
    """The sources of the chosen poses and speakers, pose after pose."""
    poses = [speakers.poses[i] for i in pose_idx]
    return RigSources(
        rig_points_m=data.speakers_rig_m,
        rotvec=np.array([p.rig_to_cam0.transform.rotvec for p in poses]),
        translation_m=np.array([p.rig_to_cam0.transform.t for p in poses]),
        pose_of_source=np.repeat(np.arange(len(poses)), len(spk_idx)),
        speaker_of_source=np.tile(spk_idx, len(poses)),
        pose_covariance=np.array([p.rig_to_cam0.cov for p in poses]),
    )


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
    source, c0, c_std = speed_of_sound_plan(m, options)
    boards, board_of_mic = board_indices(data)
    ref_board = data.reference_group
    solver_options = SolverOptions(
        speed_of_sound_m_s=c0,
        fit_speed_of_sound=source == "solved" or bool(c_std),
        speed_of_sound_prior_std_m_s=c_std if source == "known" else 1.0,
        latency=options.latency,
        reference_board=boards.index(ref_board) if ref_board in boards else None,
        refine_poses=options.refine_poses,
    )
    if options.method == "paper":
        return solve_paper_method(sources, tof, std, solver_options)
    return solve_microphones(sources, tof, std, board_of_mic=board_of_mic,
                             options=solver_options, prior_geometry=options.prior)


def _latency_layout(data: SessionData, options: CalibrationOptions) -> tuple[np.ndarray, int]:
    """Latency column of every array board (-1: the gauge board, when it records array
    microphones too) and the number of latency unknowns, for the latency model of `options`."""
    boards, _ = board_indices(data)
    ref_board = data.reference_group
    return latency_columns(len(boards), SolverOptions(
        latency=options.latency,
        reference_board=boards.index(ref_board) if ref_board in boards else None))


def bundle_priors(m: Measurements, options: CalibrationOptions) -> BundlePriors:
    """The joint fit's priors from the rig's stated tolerances and the options: each
    speaker's offset from its stated position (in the board plane: the build tolerance;
    along the normal: the acoustic centre's expected offset and its spread), the print's
    scale, each microphone's own delay, a known speed of sound (the option's, else the
    session description's air, else the session's air-sensor readings) and the cameras'
    known intrinsics (fixed, or a prior with their std)."""
    data = m.data
    rig = data.rig
    n = data.n_speakers
    mean = np.zeros((n, 3))
    std = np.zeros((n, 3))
    if options.speaker_offsets:
        mean[:, 2] = rig.acoustic_centre_m
        std[:, :2] = rig.speaker_tolerance_m
        std[:, 2] = np.hypot(rig.speaker_tolerance_m, rig.acoustic_centre_std_m)
    return BundlePriors(
        speaker_offset_mean_m=mean, speaker_offset_std_m=std,
        print_scale_std=rig.print_scale_std if options.print_scale else FIXED,
        off_axis_std_m=OFF_AXIS_STD_M if options.speaker_offsets else FIXED,
        mic_delay_std_s=(FIXED if options.mic_delay_std_s is None
                         else options.mic_delay_std_s),
        speaker_delay_std_s=np.where(np.isin(np.arange(n), list(m.lent_references)),
                                     LENT_EMISSION_STD_S, FIXED),
        speed_of_sound=known_speed_of_sound(m, options),
        speed_of_sound_step_m_s=options.speed_of_sound_step_m_s,
        **_intrinsics_priors(m, options),
    )


def _intrinsics_priors(m: Measurements, options: CalibrationOptions) -> dict[str, np.ndarray]:
    """intrinsics_mean / intrinsics_std of `BundlePriors` from the known intrinsics (none:
    every camera fitted freely)."""
    known = known_intrinsics(m.data, options)
    names = list(m.cameras.intrinsics)
    if not any(n in known for n in names):
        return {}
    mean = np.zeros((len(names), N_INTRINSICS))
    std = np.full((len(names), N_INTRINSICS), np.nan)
    for i, name in enumerate(names):
        k = known.get(name)
        if k is None:
            continue
        K = np.array(k.camera_matrix)
        mean[i] = [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *k.distortion]
        if k.use == "fixed":
            std[i] = FIXED
        elif k.std is not None:
            std[i] = k.std
    return {"intrinsics_mean": mean, "intrinsics_std": std}


def fit_joint(m: Measurements, frozen: MicrophoneSolution, options: CalibrationOptions,
              poses: np.ndarray | None = None, speakers: np.ndarray | None = None,
              start: BundleState | None = None) -> BundleSolution:
    """The optical-acoustic bundle adjustment, started from the camera-frozen solution (or
    from `start`, an earlier joint fit's state of the same problem).

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
    c_of_pose = None
    if options.speed_of_sound_per_pose:
        c_of_pose = np.full(len(board_poses), -1)
        c_of_pose[pose_idx] = np.arange(pose_idx.size)
    priors = bundle_priors(m, options)
    problem = BundleProblem(
        board_points_m=m.cameras.board_points(),
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
        reference_distance_m=data.reference_distances_m[np.tile(speaker_idx, pose_idx.size)],
        tof_speed_of_sound_m_s=NOMINAL_SPEED_OF_SOUND_M_S,
        speed_of_sound_of_pose=c_of_pose,
        priors=priors, corner_sigma_px=view_sigmas(m.cameras, steps),
    )  # fmt: skip
    sources = _rig_sources(data, m.speakers, pose_idx, speaker_idx).positions()
    if data.reference_column is not None:
        reference = multilaterate(sources, frozen.speed_of_sound_m_s
                                  * problem.reference_tof_s[:, None])[0]
    else:
        # Not recorded on the poses: no time of flight reaches the reference unknown, which
        # stays at this start (the camera) and is reported nowhere.
        reference = np.zeros(3)
    latencies = np.zeros(n_latency)
    latencies[board_column[board_column >= 0]] = frozen.latency_s[board_column >= 0]
    intrinsics, extrinsics = camera_start(m.cameras)
    start = BundleState(
        intrinsics=intrinsics, extrinsics=extrinsics,
        poses=np.array([p.rig_to_cam0.transform.params for p in board_poses]),
        microphones_m=frozen.positions_m[solved], reference_m=reference,
        speeds_of_sound_m_s=np.array([frozen.speed_of_sound_m_s]), latencies_s=latencies,
        speaker_offsets_m=priors.speaker_offset_mean_m.copy(),
    ) if start is None else start  # fmt: skip
    return fit_bundle(problem, start)


def joint_measurements(m: Measurements, bundle: BundleSolution, frozen: MicrophoneSolution,
                       options: CalibrationOptions) -> tuple[Measurements, MicrophoneSolution]:
    """The measurements with the joint fit's cameras and speaker positions, and its
    microphones in the solver's form (so that the result and the report read either)."""
    data = m.data
    solved = np.flatnonzero(np.all(np.isfinite(frozen.positions_m), axis=1))
    poses = [RigPoseInCam0(p.step, p.camera, pose_estimate(bundle, k), p.rms_px)
             for k, p in enumerate(m.speakers.poses)]
    rig_points = data.speakers_rig_m + bundle.state.speaker_offsets_m
    located = [p.locate(rig_points) for p in poses]
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
        speed_of_sound_std_m_s=bundle.speed_of_sound_std_m_s,
        latency_s=np.append(bundle.state.latencies_s, 0.0)[board_column],
        latency_std_s=np.append(bundle.std.latencies_s, 0.0)[board_column],
        pose_corrections=None, pose_correction_std=None,
        residuals_s=residuals, outliers=outliers,
        sigma_scale=bundle.sigmas.get(GROUP_TOF, float("nan")),
        chi2_per_dof=bundle.chi2_per_dof, nfev=bundle.iterations,
    )  # fmt: skip
    return joint_m, solution


def _flights(m: Measurements, mics_m: np.ndarray, solved: np.ndarray, mic_latency_s: np.ndarray,
             pose_indices: list[int],
             pose_geometry: Callable[[int], tuple[np.ndarray, np.ndarray, float]],
             off_axis_m: float = 0.0) -> Flights:
    """The modelled flights from the chosen located poses' sources to the microphones
    `solved` (NaN for the others). `pose_geometry(k)`: pose k's sources (S, 3), the rig's
    normal (3,) and c."""
    data = m.data
    shape = (len(pose_indices), data.n_speakers, len(data.mic_ids))
    delay, distance, sin_axis = (np.full(shape, np.nan) for _ in range(3))
    d_ref = data.reference_distances_m[:, None]  # per speaker
    for row, k in enumerate(pose_indices):
        sources, normal, c = pose_geometry(k)
        diff = mics_m[None] - sources[:, None]
        dist = np.linalg.norm(diff, axis=2)
        cos = diff @ normal / dist
        flight = dist - off_axis_m * (1.0 - cos) * cos
        delay[row][:, solved] = (flight - d_ref) / c + mic_latency_s
        distance[row][:, solved] = dist
        sin_axis[row][:, solved] = np.sqrt(np.maximum(1.0 - cos**2, 0.0))
    steps = tuple(m.speakers.poses[k].step for k in pose_indices)
    return Flights(steps, delay, distance, sin_axis)


def _mic_latency(data: SessionData, per_column: np.ndarray, solved: np.ndarray) -> np.ndarray:
    """Each solved microphone's board latency from per-latency-column values (the gauge 0)."""
    board_column, _ = _latency_layout(data, CalibrationOptions())
    return np.append(per_column, 0.0)[board_column[board_indices(data)[1]]][solved]


def joint_flights(m: Measurements, bundle: BundleSolution, frozen: MicrophoneSolution,
                  pose_indices: list[int]) -> Flights:
    """`_flights` of the joint fit's geometry."""
    solved = np.flatnonzero(np.all(np.isfinite(frozen.positions_m), axis=1))
    s = bundle.state
    points = m.data.speakers_rig_m + s.speaker_offsets_m

    def geometry(k: int) -> tuple[np.ndarray, np.ndarray, float]:
        rig_to_cam0 = RigidTransform.from_rotvec(s.poses[k, :3], s.poses[k, 3:])
        return rig_to_cam0.apply(points), rig_to_cam0.R[:, 2], bundle.speed_of_sound_at(k)

    return _flights(m, s.microphones_m, solved, _mic_latency(m.data, s.latencies_s, solved),
                    pose_indices, geometry, s.off_axis_m)


def frozen_flights(m: Measurements, frozen: MicrophoneSolution,
                   pose_indices: list[int]) -> Flights:
    """`_flights` of the camera-frozen solution (camera-given sources)."""
    solved = np.flatnonzero(np.all(np.isfinite(frozen.positions_m), axis=1))
    boards, board_of_mic = board_indices(m.data)
    latency = np.broadcast_to(frozen.latency_s, (len(boards),))[board_of_mic][solved]

    def geometry(k: int) -> tuple[np.ndarray, np.ndarray, float]:
        normal = m.speakers.poses[k].rig_to_cam0.transform.R[:, 2]
        return m.speakers.positions_m[k], normal, frozen.speed_of_sound_m_s

    return _flights(m, frozen.positions_m[solved], solved, latency, pose_indices, geometry)


def _responses(m: Measurements, flights: Callable[[list[int]], Flights],
               speed_of_sound_m_s: float,
               centres_hz: np.ndarray = THIRD_OCTAVE_CENTRES_HZ) -> MicrophoneResponses:
    """Every microphone's response (calibration.acoustic.responses) from the flights of a geometry,
    in the bands centred at `centres_hz`."""
    data = m.data
    chosen = evenly_spread([p.step for p in m.speakers.poses])
    return estimate_responses(m.tofs, [m.located[k] for k in chosen], flights(chosen),
                              data.fs, data.reference_distances_m, speed_of_sound_m_s,
                              data.rig.speaker_diameter_m, centres_hz)


def _frozen_responses(m: Measurements, solution: MicrophoneSolution,
                      options: CalibrationOptions) -> MicrophoneResponses:
    """The capsules' responses for their dispersion, measured on the camera-frozen geometry
    (its errors are delays, which the line through the origin takes out)."""
    return _responses(m, lambda k: frozen_flights(m, solution, k), solution.speed_of_sound_m_s,
                      dispersion_centres_hz(options.band_hz[1]))


def _emission_aligned(m: Measurements, bundle: BundleSolution) -> Measurements:
    """The measurements with the impulses of each speaker on a lent reference recording moved
    back by its emission delay after the lender's (its camera-frozen shift plus the joint
    fit's own), where a speaker correlated with its own recording has them: the responses
    read every impulse against the flights of one geometry. On a 20-pose realistic session
    with a swap and the drivers 2 us apart, 0.0367 mm without it, 0.0325 mm with identical
    drivers."""
    first_lag = m.tofs.impulse_first_lag.astype(float)
    for k, lent in m.lent_references.items():
        emission_s = lent.shift_s + float(bundle.state.speaker_delays_s[k])
        first_lag[:, k] -= emission_s * m.data.fs
    return replace(m, tofs=replace(m.tofs, impulse_first_lag=first_lag))


def _without_dispersion(m: Measurements, responses: MicrophoneResponses) -> Measurements:
    """The measurements with every microphone's measured dispersion taken out of its times
    of flight (calibration.acoustic.responses.dispersion_delays)."""
    shift = dispersion_delays(m.tofs, responses, m.data.fs)
    return replace(m, tofs=replace(m.tofs, tof_s=m.tofs.tof_s - shift))


__all__ = [
    "CalibrationInputError", "CalibrationOptions", "CalibrationRun",
    "Measurements", "calibrate", "calibrate_measured", "measure", "solve",
]
