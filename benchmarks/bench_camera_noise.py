"""Noisier cameras in the realistic lab (issue 32, the calibration side): the corner noise the
calibration estimates against the detected corners' true error, and the microphones' error
and coverage, with the world's image sensor noise and lens blur raised.

For every (noise, blur, seed) a realistic-lab session (72-microphone sphere, 0.6-1.2 m) is
simulated with `World.noise.image_noise_grey` and `image_blur_px` set (kept with --keep, so a
second run, or a run of another version of the code on the same sessions, only calibrates)
and calibrated with micam's defaults.

Columns: the detected corners' RMS error per coordinate against the true projections (what
the cameras' noise really is), the camera calibration's corner noise estimate
(calibration.camera.corner_noise; absent before it existed), the joint fit's corner sigma, the mean
and max microphone error, and the share of microphones within 2 sigma (3-D, 95.4 %) of their
reported covariance (bench_real_lab.figures).

    .venv/bin/python benchmarks/bench_camera_noise.py --poses 8 --seeds 1 --noise 30 --blur 0.6
    .venv/bin/python benchmarks/bench_camera_noise.py --keep /tmp/noisy --noise 2 30 --blur 0.6 1.5
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
from bench_real_lab import figures

from calibration.pipeline import CalibrationOptions, calibrate
from micam.simulated import prepare_simulated_capture
from sim.capture import SimulationOptions, truth_document


def session(directory: Path, poses: int, seed: int, noise_grey: float,
            blur_px: float) -> tuple[Path, dict]:
    """The realistic lab's session with the image noise and blur set (kept if recorded)."""
    path = directory / f"realistic-{poses}p-s{seed}-noise{noise_grey:g}-blur{blur_px:g}"
    if (path / "truth.json").is_file() and json.loads(
            (path / "manifest.json").read_text())["status"] == "complete":
        return path, json.loads((path / "truth.json").read_text())
    options = SimulationOptions(lab="realistic", poses=poses, seed=seed, distance_m=(0.6, 1.2))
    sim, sequencer = prepare_simulated_capture(path, options)
    sim.world.noise = replace(sim.world.noise, image_noise_grey=noise_grey,
                              image_blur_px=blur_px)
    try:
        sequencer.run()
    finally:
        sequencer.writer.close()
    return path, truth_document(sim)


def corner_figures(path: Path, truth: dict) -> dict:
    """Per camera: the detected corners' true RMS error per coordinate (against the board as
    printed: the realistic lab's print is off scale by a few 1e-4), the camera
    calibration's estimate (None before calibration.camera.corner_noise) and the joint fit's sigma,
    pixels."""
    run = calibrate(path, CalibrationOptions())
    cams = run.measurements.cameras
    built = cams.board.object_points() * truth["lab"].get("print_scale", 1.0)
    out = {}
    for name, intr in cams.intrinsics.items():
        true_cam = next(c for c in truth["cameras"] if c["name"] == name)
        ext = true_cam["from_cam0"]
        Ra, ta = cv2.Rodrigues(np.array(ext["rotvec"]))[0], np.array(ext["t_m"])
        errors = []
        for (camera, step), view in cams.views.items():
            if camera != name or not step.startswith("pose/"):
                continue
            pose = truth["poses"][int(step.split("/")[1])]["rig_to_cam0"]
            R, t = cv2.Rodrigues(np.array(pose["rotvec"]))[0], np.array(pose["t_m"])
            points = built @ (Ra @ R).T + Ra @ t + ta
            px = cv2.projectPoints(points, np.zeros(3), np.zeros(3), np.array(true_cam["K"]),
                                   np.array(true_cam["dist"]))[0].reshape(-1, 2)
            errors.append(view.corners_px - px)
        noise = getattr(intr, "noise", None)
        joint = run.result.joint_fit
        out[name] = {
            "true_rms_px": round(float(np.sqrt(np.mean(np.concatenate(errors) ** 2))), 4),
            "estimated_px": None if noise is None else round(noise.sigma_px, 4),
            "joint_fit_px": None if joint is None else round(joint.sigmas[name], 4),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=8)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--noise", type=float, nargs="+", default=[30.0],
                        help="image sensor noise, grey levels (the world's default: 2)")
    parser.add_argument("--blur", type=float, nargs="+", default=[0.6],
                        help="lens blur sigma, pixels (the world's default: 0.6)")
    parser.add_argument("--keep", type=Path, default=None,
                        help="directory to keep (and reuse) the sessions in")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        directory = args.keep or Path(tmp)
        directory.mkdir(parents=True, exist_ok=True)
        print("| noise (grey) | blur (px) | seed | corners: true RMS / estimated / joint fit "
              "(px) | mean mic error (mm) | max (mm) | within 2 sigma |")
        print("|---|---|---|---|---|---|---|")
        for noise_grey in args.noise:
            for blur in args.blur:
                for seed in args.seeds:
                    path, truth = session(directory, args.poses, seed, noise_grey, blur)
                    corners = corner_figures(path, truth)
                    mics = figures(path, truth, CalibrationOptions())
                    cells = "; ".join(f"{n} {c['true_rms_px']} / {c['estimated_px']} / "
                                      f"{c['joint_fit_px']}" for n, c in corners.items())
                    print(f"| {noise_grey:g} | {blur:g} | {seed} | {cells} | "
                          f"{mics['mean_mic_error_mm']} | {mics['max_mic_error_mm']} | "
                          f"{mics['within_2_sigma']} |", flush=True)


if __name__ == "__main__":
    main()
