"""A report a person can read: report.md with pictures, beside result.json.

Pictures: the geometry in 3D (microphones, cameras, speaker positions), residuals per
microphone and per pose, and the times of flight's quality. When the joint fit ran, the
camera-frozen solution is tabulated beside it. When the session is simulated, the errors
against its truth are tabulated too.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: reports are written on servers without a display
import matplotlib.pyplot as plt
import numpy as np

from .pipeline import CalibrationRun
from .result import CalibrationResult, compare_with_truth


def write_report(run: CalibrationRun, directory: Path, truth: dict | None = None) -> Path:
    """Write report.md and its PNGs into `directory`; return the path of report.md."""
    directory.mkdir(parents=True, exist_ok=True)
    _plot_geometry(run, directory / "geometry.png")
    _plot_residuals(run, directory / "residuals.png")
    _plot_tof_quality(run, directory / "tof_quality.png")
    path = directory / "report.md"
    path.write_text(_markdown(run, truth))
    return path


def summary_lines(run: CalibrationRun, truth: dict | None = None) -> list[str]:
    """The few lines printed at the end of `micam calibrate`."""
    r = run.result
    lines = [
        f"{len(r.microphones)} microphones from {len(r.poses)} poses "
        f"({len(r.poses) * run.data.n_speakers} sources), method {r.method}",
        f"speed of sound {r.speed_of_sound_m_s:.3f} ± {r.speed_of_sound_std_m_s:.3f} m/s; "
        f"median position std {1e3 * _median_std(run):.3f} mm; "
        f"TOF residual RMS {1e9 * r.residuals.rms_s:.1f} ns",
    ]
    if truth is not None:
        cmp = compare_with_truth(r, truth)
        lines.append(
            f"against the simulated truth: mean microphone error "
            f"{1e3 * cmp['mean_mic_error_m']:.3f} mm (max {1e3 * cmp['max_mic_error_m']:.3f}), "
            f"c error {cmp['speed_of_sound_error_m_s']:+.3f} m/s")
        if r.camera_frozen is not None:
            frozen = compare_with_truth(r, truth, camera_frozen=True)
            lines.append(
                f"camera frozen (before the joint fit): mean microphone error "
                f"{1e3 * frozen['mean_mic_error_m']:.3f} mm, c error "
                f"{frozen['speed_of_sound_error_m_s']:+.3f} m/s")
    lines.append("time: " + ", ".join(f"{k} {v:.1f} s" for k, v in r.timings_s.items()))
    return lines


def _median_std(run: CalibrationRun) -> float:
    std = np.array([np.linalg.norm(m.std_m) for m in run.result.microphones])
    return float(np.nanmedian(std)) if np.any(np.isfinite(std)) else float("nan")


def _markdown(run: CalibrationRun, truth: dict | None) -> str:
    r = run.result
    out = [f"# Calibration of session {r.session_id}", "", *[f"- {ln}" for ln in
                                                            summary_lines(run, truth)], ""]
    out += ["## Speed of sound", ""]
    if r.speed_of_sound_reference is not None:
        ref = r.speed_of_sound_reference
        out.append(f"- reference microphone fit (paper IV-G): {ref.speed_of_sound_m_s:.3f} ± "
                   f"{ref.speed_of_sound_std_m_s:.3f} m/s from {ref.n} bursts, distance "
                   f"residual RMS {1e3 * ref.residual_rms_m:.2f} mm")
    out.append(f"- used by the solver: {r.speed_of_sound_m_s:.3f} ± "
               f"{r.speed_of_sound_std_m_s:.3f} m/s")
    out += [f"- {n}" for n in r.notes if n.startswith("Speed of sound")]
    out += ["", "## Cameras", "", "| camera | fx px | fy px | cx px | cy px | RMS px | views |",
            "|---|---|---|---|---|---|---|"]
    for c in r.cameras:
        out.append(f"| {c.name} | {c.K[0][0]:.2f} | {c.K[1][1]:.2f} | {c.K[0][2]:.2f} | "
                   f"{c.K[1][2]:.2f} | {c.reprojection_rms_px:.3f} | {c.images_used} |")
    out += ["", "## Board latencies (relative to the reference microphone's board)", "",
            "| board | latency µs | std µs |", "|---|---|---|"]
    out += [f"| {b} | {1e6 * v:+.3f} | {1e6 * r.latency_std_s[b]:.3f} |"
            for b, v in r.latency_s.items()]
    out += _frozen_vs_joint(r, truth)
    q = r.tof_quality
    out += ["", "## Times of flight", "",
            f"- median SNR {q.median_snr_db:.1f} dB (5th percentile {q.p05_snr_db:.1f} dB), "
            f"median peak-to-sidelobe {q.median_peak_to_sidelobe_db:.1f} dB, median predicted "
            f"std {1e9 * q.median_predicted_std_s:.1f} ns",
            f"- residuals: RMS {1e9 * r.residuals.rms_s:.1f} ns, median |r| "
            f"{1e9 * r.residuals.median_abs_s:.1f} ns, {r.residuals.n_outliers} outliers of "
            f"{r.residuals.n_measurements + r.residuals.n_outliers}", "",
            "![geometry](geometry.png)", "", "![residuals](residuals.png)", "",
            "![TOF quality](tof_quality.png)", "", "## Notes", ""]
    out += [f"- {n}" for n in r.notes]
    return "\n".join(out) + "\n"


def _frozen_vs_joint(r: CalibrationResult, truth: dict | None) -> list[str]:
    """Markdown: the camera-frozen solution beside the joint fit, with the joint fit's noise
    estimates and outliers (nothing when the joint fit did not run)."""
    if r.camera_frozen is None or r.joint_fit is None:
        return []
    f, j = r.camera_frozen, r.joint_fit
    out = ["", "## Camera frozen vs joint fit (optical-acoustic bundle adjustment)", "",
           "| quantity | camera frozen | joint |", "|---|---|---|",
           f"| c (m/s) | {f.speed_of_sound_m_s:.3f} ± {f.speed_of_sound_std_m_s:.3f} | "
           f"{r.speed_of_sound_m_s:.3f} ± {r.speed_of_sound_std_m_s:.3f} |"]
    for c in r.cameras:
        fx, fy = f.focal_px[c.name]
        sx, sy = f.focal_std_px[c.name]
        std = c.intrinsics_std or [float("nan")] * 2
        out.append(f"| {c.name} fx, fy (px) | {fx:.2f} ± {sx:.2f}, {fy:.2f} ± {sy:.2f} | "
                   f"{c.K[0][0]:.2f} ± {std[0]:.2f}, {c.K[1][1]:.2f} ± {std[1]:.2f} |")
    for b, v in r.latency_s.items():
        out.append(f"| latency {b} (µs) | {1e6 * f.latency_s[b]:+.3f} | {1e6 * v:+.3f} ± "
                   f"{1e6 * r.latency_std_s[b]:.3f} |")
    if truth is not None:
        errors = [compare_with_truth(r, truth, camera_frozen=True), compare_with_truth(r, truth)]
        for key, unit, factor in (("mean_mic_error_m", "mm", 1e3), ("max_mic_error_m", "mm", 1e3),
                                  ("speed_of_sound_error_m_s", "m/s", 1.0),
                                  ("max_focal_error_rel", "%", 100.0),
                                  ("max_latency_error_s", "µs", 1e6)):
            if key in errors[0]:
                out.append(f"| error vs truth: {key} ({unit}) | "
                           + " | ".join(f"{factor * e[key]:.4f}" for e in errors) + " |")
    sigmas = ", ".join(f"{k} {v:.3g}" for k, v in j.sigmas.items())
    outliers = ", ".join(f"{k} {v}" for k, v in j.corner_outliers.items())
    out += ["", f"- noise estimated from the residuals (px per coordinate for corners, factor "
                f"on the predicted std for times of flight): {sigmas}",
            f"- outliers left out: corners {outliers}; times of flight {j.tof_outliers}; "
            f"reference times of flight {j.reference_tof_outliers}",
            f"- chi² per degree of freedom {j.chi2_per_dof:.2f}, {j.iterations} iterations"]
    return out


def _plot_geometry(run: CalibrationRun, path: Path) -> None:
    mics = run.result.positions()
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    sources = run.speakers.positions_m.reshape(-1, 3)
    ax.scatter(sources[:, 0], sources[:, 2], -sources[:, 1], s=4, c="tab:orange",
               label="speaker positions")
    ax.scatter(mics[:, 0], mics[:, 2], -mics[:, 1], s=10, c="tab:blue", label="microphones")
    for cam in run.result.cameras:
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(cam.from_cam0.rotvec).as_matrix()
        centre = -R.T @ np.array(cam.from_cam0.t_m)
        ax.scatter(*centre[[0, 2]], -centre[1], marker="^", s=60, c="k")
        ax.text(centre[0], centre[2], -centre[1], cam.name)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m, forward)")
    ax.set_zlabel("-y (m, up)")
    ax.legend(loc="upper left")
    ax.set_title("Camera-0 frame: microphones, cameras, speaker positions")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_residuals(run: CalibrationRun, path: Path) -> None:
    res = np.where(run.solution.outliers, np.nan, run.solution.residuals_s)
    n_spk = run.data.n_speakers
    per_mic = np.sqrt(np.nanmean(res**2, axis=0)) * 1e9
    per_pose = np.sqrt(np.nanmean(res.reshape(-1, n_spk * res.shape[1]) ** 2, axis=1)) * 1e9
    fig, (a, b) = plt.subplots(2, 1, figsize=(8, 6))
    a.bar(np.arange(per_mic.size), per_mic)
    a.set_xlabel("microphone")
    a.set_ylabel("residual RMS (ns)")
    b.bar(np.arange(per_pose.size), per_pose, color="tab:green")
    b.set_xlabel("pose")
    b.set_ylabel("residual RMS (ns)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_tof_quality(run: CalibrationRun, path: Path) -> None:
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.5))
    a.hist(run.tofs.snr_db.ravel(), bins=40)
    a.set_xlabel("in-band SNR (dB)")
    a.set_ylabel("measurements")
    finite = run.tofs.peak_to_sidelobe_db[np.isfinite(run.tofs.peak_to_sidelobe_db)]
    b.hist(finite, bins=40, color="tab:purple")
    b.set_xlabel("peak-to-sidelobe (dB)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
