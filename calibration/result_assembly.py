"""result.json from a calibration's measurements and solutions: the microphones, c, the
latencies, the cameras and board poses, the residuals and the TOF quality, the notes, and the
joint fit's additions (its noise figures, the rig it found, the camera-frozen solution beside
it, the microphones' delays and responses).

Apart from the pipeline that runs the stages (calibration.pipeline calls these after its
fits), so that each reads on its own.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .solve.bundle import BundleSolution, board_views
from .camera.camera_calibration import CameraCalibration
from .plan import (
    _bundle_steps,
    board_indices,
    known_intrinsics,
    known_speed_of_sound,
    speed_of_sound_plan,
)
from .acoustic.responses import MicrophoneResponses
from .result import (
    BoardBowResult,
    CalibrationResult,
    CameraFrozenResult,
    CameraResult,
    JointFitResult,
    MicrophoneResponse,
    MicrophoneResponsesResult,
    MicrophoneResult,
    PoseResult,
    ResidualStats,
    LentReferenceResult,
    RigFitResult,
    SpeedOfSoundReference,
    TofQuality,
    TransformResult,
)
from .session_data import SessionData
from .solve.solver import MicrophoneSolution
from .camera.speakers import SpeakerPositions

if TYPE_CHECKING:
    from .pipeline import CalibrationOptions, Measurements

CONFOUND_NOTE = (
    "The speed of sound and the metric scale are confounded: scaling every length and c by "
    "one factor leaves every time of flight unchanged. The joint fit takes the scale from the "
    "absolute references it is given (the print's stated scale and tolerance, the speakers' "
    "stated positions and tolerance, a measured air state); with none of them measured well, "
    "c is the paper's 'scaled' c (IV-G)."
)


def _per_board(boards: list[str], values: np.ndarray) -> dict[str, float]:
    """Board serial -> value; a single value (no or one common latency) applies to all."""
    values = np.broadcast_to(np.asarray(values, dtype=float), (len(boards),))
    return {b: float(v) for b, v in zip(boards, values, strict=True)}


def _finite_median(values: np.ndarray) -> float | None:
    """The median of `values`, or None where it is not finite (JSON has no infinity: it was
    written as null, which the result's own model then refused to read back)."""
    median = float(np.median(values))
    return median if np.isfinite(median) else None


def _finite_or_none(value: float, digits: int = 4) -> float | None:
    """`value` rounded, or None where it is not finite (JSON has no NaN)."""
    return round(value, digits) if np.isfinite(value) else None


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
    source, c0, c_std = speed_of_sound_plan(m, options)
    notes.append(_speed_of_sound_note(m, options, source, c0, c_std))
    notes += [f"camera {name}: intrinsics given as {known.use}"
              + ("" if known.use == "fixed" or known.std is not None
                 else "; without their std the joint fit refines them freely")
              for name, known in known_intrinsics(data, options).items()]
    notes += m.notes
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
        speed_of_sound_from=source,
        speed_of_sound_known_m_s=known_speed_of_sound(m, options),
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
            median_predicted_std_s=_finite_median(tofs.std_s[located]),
            weighting=m.weighting, echo_ratio=_finite_or_none(tofs.echo_ratio(located))),
        timings_s=dict(timings),
        notes=notes,
        findings=m.findings,
        latency_gauge_board=data.reference_group,
        board_bow=(None if cams.bow is None else BoardBowResult(
            sag_m=cams.bow.sag_m, sag_std_m=cams.bow.std_m, n_views=cams.bow.n_views)),
    )


def _speed_of_sound_note(m: Measurements, options: CalibrationOptions, source: str, c0: float,
                         c_std: float | None) -> str:
    """Where the camera-frozen solver's c came from, for a person."""
    if source == "reference_microphone":
        return ("Speed of sound (camera frozen): fixed at the reference-microphone fit (paper "
                "IV-G, the reference microphone on its stand in every pose recording).")
    why = ("the pose recordings do not hold the reference microphone"
           if m.data.reference_column is None else
           "the session has no located image of the reference microphone on its stand"
           if m.reference is None else "--speed-of-sound solve")
    if source == "known":
        air = m.data.description.air
        given = ("given" if options.speed_of_sound_prior is not None
                 else air.source() if air is not None else "the session's air sensor")
        return (f"Speed of sound (camera frozen): held to the known {c0:.3f} ± {c_std:.3f} m/s "
                f"({given}), because {why}.")
    return (f"Speed of sound (camera frozen): solved from the times of flight (no known c), "
            f"because {why}; give a measured air temperature or c to constrain it.")


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


def _frozen_summary(m: Measurements, sol: MicrophoneSolution,
                    options: CalibrationOptions) -> CameraFrozenResult:
    """The camera-frozen solution, for the result beside the joint one."""
    boards, _ = board_indices(m.data)
    intr = m.cameras.intrinsics
    return CameraFrozenResult(
        microphones=_microphone_results(m.data, sol),
        speed_of_sound_from=speed_of_sound_plan(m, options)[0],
        speed_of_sound_m_s=sol.speed_of_sound_m_s,
        speed_of_sound_std_m_s=(sol.speed_of_sound_std_m_s if m.reference_fit is None
                                else m.reference_fit.speed_of_sound_std_m_s),
        latency_s=_per_board(boards, sol.latency_s),
        latency_std_s=_per_board(boards, sol.latency_std_s),
        focal_px={n: (float(c.K[0, 0]), float(c.K[1, 1])) for n, c in intr.items()},
        focal_std_px={n: (float(c.std[0]), float(c.std[1])) for n, c in intr.items()},
    )


def _with_delays(mics: list[MicrophoneResult], bundle: BundleSolution,
                 frozen: MicrophoneSolution) -> list[MicrophoneResult]:
    """The microphones with their own delays, where the joint fit estimated them."""
    if not bundle.std.mic_delays_s.any():
        return mics
    solved = np.flatnonzero(np.all(np.isfinite(frozen.positions_m), axis=1))
    out = list(mics)
    for i, m in enumerate(solved):
        out[m] = mics[m].model_copy(update={
            "delay_s": float(bundle.state.mic_delays_s[i]),
            "delay_std_s": float(bundle.std.mic_delays_s[i])})
    return out


def _responses_result(m: Measurements, est: MicrophoneResponses) -> MicrophoneResponsesResult:
    """The responses as result.json carries them."""
    data = m.data
    return MicrophoneResponsesResult(
        frequencies_hz=est.frequencies_hz.tolist(), n_sources=est.n_sources,
        microphones=[MicrophoneResponse(
            id=int(mic_id), gain=est.gain[i].tolist(), phase_rad=est.phase_rad[i].tolist(),
            gain_std=est.gain_std[i].tolist(), phase_std_rad=est.phase_std_rad[i].tolist())
            for i, mic_id in enumerate(data.mic_ids) if np.all(np.isfinite(est.gain[i]))])


def _rig_summary(m: Measurements, bundle: BundleSolution) -> RigFitResult:
    """The rig as the joint fit found it: speaker positions, print scale, and the emission
    delays of speakers measured on another's reference recording."""
    offsets = bundle.state.speaker_offsets_m
    std = bundle.std.speaker_offsets_m
    return RigFitResult(
        speakers_rig_m=[_vec(p) for p in m.data.speakers_rig_m + offsets],
        speakers_rig_std_m=[_vec(s) for s in std], offsets_m=[_vec(o) for o in offsets],
        print_scale=bundle.state.print_scale, print_scale_std=float(bundle.std.print_scale),
        acoustic_centre_off_axis_m=bundle.state.off_axis_m,
        acoustic_centre_off_axis_std_m=float(bundle.std.off_axis_m),
        lent_references=[LentReferenceResult(
            speaker=k, reference_of=lent.lender,
            emission_delay_s=lent.shift_s + float(bundle.state.speaker_delays_s[k]),
            emission_delay_std_s=float(bundle.std.speaker_delays_s[k]))
            for k, lent in sorted(m.lent_references.items())])


def _joint_summary(m: Measurements, bundle: BundleSolution,
                   options: CalibrationOptions) -> JointFitResult:
    """The joint fit's noise estimates, outliers and convergence, for the result."""
    names = list(m.cameras.intrinsics)
    view_camera = board_views(m.cameras, _bundle_steps(m)[0])[0]
    per_pose = bundle.state.speeds_of_sound_m_s.size > 1
    on_stand = m.data.reference_column is not None
    return JointFitResult(
        sigmas=bundle.sigmas,
        corner_outliers={n: int(bundle.corner_outliers[view_camera == i].sum())
                         for i, n in enumerate(names)},
        tof_outliers=int(bundle.tof_outliers.sum()),
        reference_tof_outliers=int(bundle.reference_outliers.sum()),
        chi2_per_dof=bundle.chi2_per_dof,
        iterations=bundle.iterations,
        reference_microphone_m=(_vec(bundle.state.reference_m) if on_stand else None),
        reference_microphone_std_m=(_vec(bundle.std.reference_m) if on_stand else None),
        speed_of_sound_per_pose_m_s=(bundle.state.speeds_of_sound_m_s.tolist() if per_pose
                                     else None),
        speed_of_sound_per_pose_std_m_s=(bundle.std.speeds_of_sound_m_s.tolist() if per_pose
                                         else None),
    )


def _camera_result(cams: CameraCalibration, name: str) -> CameraResult:
    intr = cams.intrinsics[name]
    ext = cams.cam_from_cam0[name]
    missed = [m.step for m in cams.missed if m.camera == name]
    return CameraResult(
        name=name, width=intr.width, height=intr.height, K=intr.K.tolist(),
        dist=intr.dist.ravel().tolist(),
        from_cam0=TransformResult(rotvec=_vec(ext.cam0_to_cam.rotvec),
                                  t_m=_vec(ext.cam0_to_cam.t)),
        reprojection_rms_px=float(intr.rms_px), images_used=int(intr.n_views),
        images_without_board=missed, intrinsics_std=intr.std.tolist(),
        corner_noise_px=intr.noise.sigma_px, corner_noise_std_px=intr.noise.std_px,
        corner_noise_corners=intr.noise.n_corners,
        view_corner_noise_px={v.step: v.sigma_px for (c, _), v in cams.views.items()
                              if c == name and v.sigma_px != intr.noise.sigma_px})


def _pose_result(data: SessionData, speakers: SpeakerPositions, i: int) -> PoseResult:
    pose = speakers.poses[i]
    return PoseResult(
        index=int(pose.step.split("/")[1]), step=pose.step, camera=pose.camera,
        rig_to_cam0=TransformResult(rotvec=_vec(pose.rig_to_cam0.transform.rotvec),
                                    t_m=_vec(pose.rig_to_cam0.transform.t)),
        speakers_m=[_vec(p) for p in speakers.positions_m[i]],
        speakers_std_m=[_vec(np.sqrt(np.diag(c))) for c in speakers.cov_m2[i]],
        reprojection_rms_px=float(pose.rms_px) if np.isfinite(pose.rms_px) else None)
