"""A report a person can read: report.md with figures, beside result.json.

Figures (`calibration.figures`, one style): the array geometry in three equal-aspect views
with magnified error vectors against the simulated truth or the prior and the uncertainty
ellipses (geometry.png), the time-of-flight residuals by microphone, pose, board, distance and
angle (residuals.png), the corner reprojection residuals per camera (corners.png) and the
times of flight's quality (tof_quality.png). When the joint fit ran, the camera-frozen
solution is tabulated beside it; when the session is simulated, the errors against its truth
too. Repeated notes (an image without a checkerboard, per camera) are grouped.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from acquisition.contracts.step_ids import pose_index, pose_step
from kernel.rigid import RigidTransform, kabsch

from .figures.geometry import ArrayPicture, CameraMark, geometry_figure
from .figures.residuals import (
    CornerResiduals,
    TofResiduals,
    corner_residual_figure,
    tof_quality_figure,
    tof_residual_figure,
)
from .figures.style import save_all
from .pipeline import CalibrationRun
from .plan import _bundle_steps
from .result import CalibrationResult, CameraResult, TofQuality, compare_with_truth

FIGURES = ("geometry.png", "residuals.png", "corners.png", "tof_quality.png")


def significant(value: float, digits: int = 2, signed: bool = False) -> str:
    """`value` with `digits` significant digits and no exponent ("0.00031", "12", "0.041"),
    so that a small number never prints as 0.0."""
    if not math.isfinite(value):
        return str(value)
    sign = "+" if signed else ""
    if value == 0:
        return f"{0:{sign}.{digits - 1}f}"
    decimals = max(0, digits - 1 - math.floor(math.log10(abs(value))))
    return f"{value:{sign}.{decimals}f}"


def write_report(run: CalibrationRun, directory: Path, truth: dict | None = None,
                 prior_m: np.ndarray | None = None) -> Path:
    """Write report.md and its figures into `directory`; return the path of report.md.

    Args:
        truth: a simulated session's truth.json: errors and error vectors against it.
        prior_m: (M, 3) the prior geometry the calibration used (any frame, the session's
            microphone order): without a truth, the error vectors are drawn against it after
            its best rigid fit to the result.
    """
    directory.mkdir(parents=True, exist_ok=True)
    picture = array_picture(run.result, truth, prior_m, run.solution.covariance_m2,
                            run.measurements.cameras.uncalibrated)
    located = run.measurements.located
    save_all([
        (lambda: geometry_figure(picture), directory / "geometry.png"),
        (lambda: tof_residual_figure(tof_residuals(run)), directory / "residuals.png"),
        (lambda: corner_residual_figure(corner_residuals(run)), directory / "corners.png"),
        (lambda: tof_quality_figure(run.tofs.snr_db[located],
                                    run.tofs.peak_to_sidelobe_db[located]),
         directory / "tof_quality.png"),
    ])
    path = directory / "report.md"
    path.write_text(_markdown(run, truth))
    return path


def _camera_mark(name: str, rotvec, t_m, calibrated: bool) -> CameraMark:
    """A camera at x_cam = R x_cam0 + t: its centre and optical axis (z) in camera 0."""
    cam_to_cam0 = RigidTransform.from_rotvec(rotvec, t_m).inverse()
    return CameraMark(name, cam_to_cam0.t, cam_to_cam0.R[:, 2], calibrated)


def array_picture(result: CalibrationResult, truth: dict | None = None,
                  prior_m: np.ndarray | None = None, covariance_m2: np.ndarray | None = None,
                  uncalibrated: dict[str, str] | None = None) -> ArrayPicture:
    """What geometry.png shows for a calibration result (see `figures.geometry`).

    Args:
        truth: truth.json of a simulated session: the reference, and the cameras the result
            lacks (drawn hollow).
        prior_m: without a truth, the prior geometry (any frame, the result's microphone
            order), rigidly fitted to the result, is the reference.
        covariance_m2: (M, 3, 3) the microphones' covariances; default: the result's standard
            deviations (result.json keeps no correlations, so the ellipses are axis-aligned).
        uncalibrated: cameras left out of the calibration, with the reason (default: those of
            the truth that the result lacks).
    """
    ids = [m.id for m in result.microphones]
    estimate = result.positions()
    reference, label = None, "reference"
    if truth is not None:
        by_id = {int(m["id"]): m["position_m"] for m in truth["microphones"]}
        reference, label = np.array([by_id[i] for i in ids], dtype=np.float64), "simulated truth"
    elif prior_m is not None:
        ok = np.all(np.isfinite(estimate), axis=1)
        reference = kabsch(prior_m[ok], estimate[ok]).apply(prior_m)
        label = "prior (rigidly fitted)"
    if covariance_m2 is None:
        covariance_m2 = np.array([np.diag(np.square(m.std_m)) for m in result.microphones])
    calibrated = {c.name for c in result.cameras}
    true_cameras = {c["name"]: c for c in (truth or {}).get("cameras", [])}
    if uncalibrated is None:
        uncalibrated = {n: "not calibrated" for n in true_cameras if n not in calibrated}
    cameras = [_camera_mark(c.name, c.from_cam0.rotvec, c.from_cam0.t_m, True)
               for c in result.cameras]
    missing = []
    for name, why in uncalibrated.items():
        if name in true_cameras:
            cam = true_cameras[name]["from_cam0"]
            cameras.append(_camera_mark(name, cam["rotvec"], cam["t_m"], False))
        else:
            missing.append(f"{name} ({why})")
    sources = np.array([p.speakers_m for p in result.poses], dtype=np.float64).reshape(-1, 3)
    return ArrayPicture(estimate, covariance_m2, reference, label, tuple(cameras), sources,
                        tuple(missing))


def tof_residuals(run: CalibrationRun) -> TofResiduals:
    """The solution's time-of-flight residuals (outliers and unplaced microphones out)."""
    sol = run.solution
    placed = np.all(np.isfinite(sol.positions_m), axis=1)
    residuals = np.where(sol.outliers, np.nan, sol.residuals_s)[:, placed]
    poses = np.array([pose_index(p.step) for p in run.speakers.poses])
    return TofResiduals(
        residuals_s=residuals,
        pose_of_source=np.repeat(poses, run.data.n_speakers),
        sources_m=run.speakers.positions_m.reshape(-1, 3),
        mics_m=sol.positions_m[placed],
        mic_ids=np.asarray(run.data.mic_ids)[placed],
        boards=tuple(b for b, ok in zip(run.data.mic_boards, placed, strict=True) if ok))


def corner_residuals(run: CalibrationRun) -> list[CornerResiduals]:
    """Every calibrated camera's corner residuals: the joint fit's when it ran (outliers
    left out), else each view's reprojection with its own board pose."""
    from .solve.bundle import board_views

    cams = run.measurements.cameras
    names = list(cams.intrinsics)
    if run.bundle is not None:
        view_camera, view_pose, corners = board_views(cams, _bundle_steps(run.measurements)[0])
        residuals = run.bundle.corner_residuals_px
        # neither the outliers nor the corners a view recovered in part lacks (NaN)
        kept = ~run.bundle.corner_outliers & np.isfinite(residuals).all(axis=2)
    else:
        keys = list(cams.views)
        view_camera = np.array([names.index(name) for name, _ in keys])
        view_pose = np.arange(len(keys))
        corners = np.array([cams.views[k].corners_px for k in keys])
        residuals = np.array([_reprojection_residual(run, k) for k in keys])
        kept = np.isfinite(corners).all(axis=2)
    out = []
    for i, name in enumerate(names):
        views = view_camera == i
        intr = cams.intrinsics[name]
        out.append(CornerResiduals(name, residuals[views][kept[views]],
                                   corners[views][kept[views]], intr.K[:2, 2],
                                   len(np.unique(view_pose[views]))))
    return out


def _reprojection_residual(run: CalibrationRun, key: tuple[str, str]) -> np.ndarray:
    """Detected minus projected corners (n, 2) of one camera-only board view."""
    cams = run.measurements.cameras
    view, intr = cams.views[key], cams.intrinsics[key[0]]
    projected, _ = cv2.projectPoints(cams.board_points(), view.rig_to_cam.transform.rotvec,
                                     view.rig_to_cam.transform.t, intr.K, intr.dist)
    return view.corners_px - projected.reshape(-1, 2)


def summary_lines(run: CalibrationRun, truth: dict | None = None) -> list[str]:
    """The few lines printed at the end of `micam calibrate`."""
    r = run.result
    c_std = (f" ± {significant(r.speed_of_sound_std_m_s)}"
             if math.isfinite(r.speed_of_sound_std_m_s) else "")
    median_std = _median_std(run)
    std = (f"median position std {significant(1e3 * median_std)} mm"
           if math.isfinite(median_std) else f"no position std (method {r.method} gives none)")
    left_out = len(r.left_out_microphones())
    without = f" ({left_out} left out: see the findings)" if left_out else ""
    lines = [
        f"{len(r.microphones)} microphones{without} from {len(r.poses)} poses "
        f"({len(r.poses) * run.data.n_speakers} sources), method {r.method}",
        f"speed of sound {r.speed_of_sound_m_s:.3f}{c_std} m/s; {std}; TOF residual RMS "
        f"{significant(1e9 * r.residuals.rms_s)} ns",
    ]
    if truth is not None:
        cmp = compare_with_truth(r, truth)
        lines.append(
            f"against the simulated truth: mean microphone error "
            f"{significant(1e3 * cmp['mean_mic_error_m'])} mm (max "
            f"{significant(1e3 * cmp['max_mic_error_m'])} mm), c error "
            f"{significant(cmp['speed_of_sound_error_m_s'], signed=True)} m/s")
        if r.camera_frozen is not None:
            frozen = compare_with_truth(r, truth, camera_frozen=True)
            lines.append(
                f"camera frozen (before the joint fit): mean microphone error "
                f"{significant(1e3 * frozen['mean_mic_error_m'])} mm, c error "
                f"{significant(frozen['speed_of_sound_error_m_s'], signed=True)} m/s")
    lines += [line for c in r.cameras if (line := corner_noise_line(c))]
    if r.board_bow is not None:
        bow = r.board_bow
        lines.append(f"board bow (the pattern's centre out of the plane of its corners): "
                     f"{significant(1e3 * bow.sag_m, signed=True)} ± "
                     f"{significant(1e3 * bow.sag_std_m)} mm from {bow.n_views} views")
    lines.append("time: " + ", ".join(f"{k} {v:.1f} s" for k, v in r.timings_s.items()))
    return lines


def corner_noise_line(c: CameraResult) -> str | None:
    """"camera cam0: corner noise 0.084 px (estimated from 1,560 corners)", with the views
    whose noise differs; None for a result without the estimate."""
    if c.corner_noise_px is None:
        return None
    own = ""
    if c.view_corner_noise_px:
        own = "; its own in " + ", ".join(f"{step} {significant(v)} px"
                                          for step, v in c.view_corner_noise_px.items())
    return (f"camera {c.name}: corner noise {significant(c.corner_noise_px)} px (estimated "
            f"from {c.corner_noise_corners:,} corners){own}")


def _median_std(run: CalibrationRun) -> float:
    std = np.array([np.linalg.norm(m.std_m) for m in run.result.microphones])
    return float(np.nanmedian(std)) if np.any(np.isfinite(std)) else float("nan")


def step_ranges(steps: list[str]) -> str:
    """Steps as compact ranges: "pose/0001-0003, pose/0009, refmic"."""
    numbers = sorted(n for s in steps if (n := pose_index(s)) is not None)
    parts: list[str] = []
    start = prev = None
    for n in [*numbers, None]:
        if n is not None and prev is not None and n == prev + 1:
            prev = n
            continue
        if start is not None:
            parts.append(pose_step(start) + (f"-{prev:04d}" if prev != start else ""))
        start = prev = n
    return ", ".join(parts + sorted(s for s in steps if pose_index(s) is None))


def grouped_notes(run: CalibrationRun) -> list[str]:
    """The result's notes with the images skipped by each camera for one reason grouped
    into one line, and repeated notes counted."""
    missed = run.measurements.cameras.missed
    per_image = {f"{m.camera} {m.step}: {m.reason}" for m in missed}
    groups: dict[tuple[str, str], list[str]] = {}
    for m in missed:
        groups.setdefault((m.camera, m.reason), []).append(m.step)
    lines = [f"{camera}: {reason} in {len(steps)} image{'s' if len(steps) > 1 else ''} "
             f"({step_ranges(steps)})" for (camera, reason), steps in sorted(groups.items())]
    counts = Counter(n for n in run.result.notes if n not in per_image)
    lines += [n if k == 1 else f"{n} (x{k})" for n, k in counts.items()]
    return lines


def _markdown(run: CalibrationRun, truth: dict | None) -> str:
    r = run.result
    out = [f"# Calibration of session {r.session_id}", "", *[f"- {ln}" for ln in
                                                            summary_lines(run, truth)], ""]
    out += _findings(r)
    out += ["## Speed of sound", ""]
    if r.speed_of_sound_reference is not None:
        ref = r.speed_of_sound_reference
        out.append(f"- reference microphone fit (paper IV-G): {ref.speed_of_sound_m_s:.3f} ± "
                   f"{significant(ref.speed_of_sound_std_m_s)} m/s from {ref.n} bursts, "
                   f"distance residual RMS {significant(1e3 * ref.residual_rms_m)} mm")
    out.append(f"- used by the solver: {r.speed_of_sound_m_s:.3f} ± "
               f"{significant(r.speed_of_sound_std_m_s)} m/s")
    out += [f"- {n}" for n in r.notes if n.startswith("Speed of sound")]
    out += ["", "## Cameras", "", "| camera | fx px | fy px | cx px | cy px | RMS px | views |",
            "|---|---|---|---|---|---|---|"]
    for c in r.cameras:
        out.append(f"| {c.name} | {c.K[0][0]:.2f} | {c.K[1][1]:.2f} | {c.K[0][2]:.2f} | "
                   f"{c.K[1][2]:.2f} | {c.reprojection_rms_px:.3f} | {c.images_used} |")
    out += ["", "## Board latencies (relative to the reference microphone's board)", "",
            "| board | latency µs | std µs |", "|---|---|---|"]
    out += [f"| {b} | {1e6 * v:+.3f} | {significant(1e6 * r.latency_std_s[b])} |"
            for b, v in r.latency_s.items()]
    out += _frozen_vs_joint(r, truth)
    q = r.tof_quality
    out += ["", "## Times of flight", "",
            f"- median SNR {q.median_snr_db:.1f} dB (5th percentile {q.p05_snr_db:.1f} dB), "
            f"median peak-to-sidelobe {q.median_peak_to_sidelobe_db:.1f} dB, median predicted "
            + ("std: none (more than half too faint to predict one)"
               if q.median_predicted_std_s is None
               else f"std {significant(1e9 * q.median_predicted_std_s)} ns"),
            *_weighting_line(q),
            f"- residuals: RMS {significant(1e9 * r.residuals.rms_s)} ns, median |r| "
            f"{significant(1e9 * r.residuals.median_abs_s)} ns, {r.residuals.n_outliers} "
            f"outliers of {r.residuals.n_measurements + r.residuals.n_outliers}", "",
            "## Figures", "",
            "The array in three views; each arrow is a microphone's error, magnified by the "
            "factor in the legend, from its reference position; an arrow ending outside its "
            "ellipse is an error larger than the calibration's 95 % uncertainty.", "",
            "![geometry](geometry.png)", "",
            "Time-of-flight residuals: a trend against distance or angle, or one board or pose "
            "standing out, is a model error.", "",
            "![residuals](residuals.png)", "",
            "Corner reprojection residuals per camera: round and without a trend with the "
            "radius when the camera model fits.", "",
            "![corners](corners.png)", "", "![TOF quality](tof_quality.png)", "",
            "## Notes", ""]
    out += [f"- {n}" for n in grouped_notes(run)]
    return "\n".join(out) + "\n"


def _findings(r: CalibrationResult) -> list[str]:
    """The section "Mistakes of the capture": one entry per finding (none: no section)."""
    if not r.findings:
        return []
    out = ["## Mistakes of the capture", "",
           "Found in the recordings themselves; what was corrected or left out is said in each "
           "entry, and the result above is computed without what was left out.", ""]
    for f in r.findings:
        where = f" (wired at {', '.join(f.channels)})" if f.channels else ""
        out.append(f"- **{f.kind}** ({f.action}): {f.evidence}{where}. "
                   f"{f.advice[0].upper()}{f.advice[1:]}.")
    return [*out, ""]


def _frozen_vs_joint(r: CalibrationResult, truth: dict | None) -> list[str]:
    """Markdown: the camera-frozen solution beside the joint fit, with the joint fit's noise
    estimates and outliers (nothing when the joint fit did not run)."""
    if r.camera_frozen is None or r.joint_fit is None:
        return []
    f, j = r.camera_frozen, r.joint_fit
    out = ["", "## Camera frozen vs joint fit (optical-acoustic bundle adjustment)", "",
           "| quantity | camera frozen | joint |", "|---|---|---|",
           f"| c (m/s) | {f.speed_of_sound_m_s:.3f} ± {significant(f.speed_of_sound_std_m_s)} | "
           f"{r.speed_of_sound_m_s:.3f} ± {significant(r.speed_of_sound_std_m_s)} |"]
    for c in r.cameras:
        fx, fy = f.focal_px[c.name]
        sx, sy = f.focal_std_px[c.name]
        std = c.intrinsics_std or [float("nan")] * 2
        out.append(f"| {c.name} fx, fy (px) | {fx:.2f} ± {sx:.2f}, {fy:.2f} ± {sy:.2f} | "
                   f"{c.K[0][0]:.2f} ± {std[0]:.2f}, {c.K[1][1]:.2f} ± {std[1]:.2f} |")
    for b, v in r.latency_s.items():
        out.append(f"| latency {b} (µs) | {1e6 * f.latency_s[b]:+.3f} | {1e6 * v:+.3f} ± "
                   f"{significant(1e6 * r.latency_std_s[b])} |")
    if truth is not None:
        errors = [compare_with_truth(r, truth, camera_frozen=True), compare_with_truth(r, truth)]
        for key, unit, factor in (("mean_mic_error_m", "mm", 1e3), ("max_mic_error_m", "mm", 1e3),
                                  ("speed_of_sound_error_m_s", "m/s", 1.0),
                                  ("max_focal_error_rel", "%", 100.0),
                                  ("max_latency_error_s", "µs", 1e6)):
            if key in errors[0]:
                out.append(f"| error vs truth: {key} ({unit}) | "
                           + " | ".join(significant(factor * e[key]) for e in errors) + " |")
    sigmas = ", ".join(f"{k} {v:.3g}" for k, v in j.sigmas.items())
    outliers = ", ".join(f"{k} {v}" for k, v in j.corner_outliers.items())
    out += ["", f"- noise estimated from the residuals (px per coordinate for corners, factor "
                f"on the predicted std for times of flight): {sigmas}",
            f"- outliers left out: corners {outliers}; times of flight {j.tof_outliers}; "
            f"reference times of flight {j.reference_tof_outliers}",
            f"- chi² per degree of freedom {j.chi2_per_dof:.2f}, {j.iterations} iterations"]
    return out


def _weighting_line(q: TofQuality) -> list[str]:
    """The weighting the times of flight were correlated with and why, for a person."""
    if q.weighting is None:
        return []
    echo = ("" if q.echo_ratio is None else
            f" (echo ratio {q.echo_ratio:.3f}: " + ("free field" if q.weighting == "matched"
                                                    else "reflections or ringing") + ")")
    return [f"- weighting: {q.weighting}{echo}"]
