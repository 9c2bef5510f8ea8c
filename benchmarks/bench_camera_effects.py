"""The realistic lab's cameras (issue 32): corner reprojection residuals per camera effect.

For every row a world with only that lab effect (or none, or every camera effect; "mjpeg":
frames delivered as MJPEG at quality 80, the mjpeg mistake, alone or with every effect) renders
camera 0's images of the same rig poses (the 48-microphone scatter's single 1280 x 960 camera,
so that no acoustics are simulated), and the calibration's own camera calibration
(calibration.camera.camera_calibration.calibrate_images: its corner detectors and OpenCV's
5-coefficient fit) reports its RMS reprojection residual, the figure `micam calibrate` puts in
result.json. Also: the corners' own error, the RMS distance of the found corners from the
true corners' projections (the bowed face's, by the true camera: the simulated corner noise a
calibration's noise estimate should recover, which the residual understates by the fitted
unknowns' share and overstates by what the model cannot fit), the focal length's error
against the simulated truth, the calibration's estimate of the corner noise per pixel
coordinate (calibration.camera.corner_noise) beside the true one (the standard deviation of
the corners' errors per coordinate about their mean), and the mean time to render one image
(the cost of the effects; the rays of a camera are computed once before).

    .venv/bin/python benchmarks/bench_camera_effects.py [--poses 8] [--seeds 0]
    .venv/bin/python benchmarks/bench_camera_effects.py --rows none all --poses 30

Printed as a markdown table, written as JSON to benchmarks/results/camera_effects.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from calibration.camera.camera_calibration import calibrate_images
from calibration.camera.corners import Checkerboard
from sim.cameras import SimulatedCamera
from sim.capture import SimulationOptions, world_for
from sim.optics import CAMERA_EFFECTS
from sim.mistakes.plan import NO_MISTAKES, Mistakes
from sim.setups import Setups, pose_setup

JPEG_QUALITY = 80
ROWS = ("none", *CAMERA_EFFECTS, "mjpeg", "all", "all+mjpeg")


def measure(row: str, poses: int, seed: int) -> dict:
    """Render camera 0's view of `poses` rig poses in the world of `row` and calibrate it."""
    effects = {"none": (), "mjpeg": (), "all": CAMERA_EFFECTS,
               "all+mjpeg": CAMERA_EFFECTS}.get(row, (row,))
    options = SimulationOptions(array="scatter48", poses=poses, seed=seed, effects=effects)
    world, rig_poses = world_for(options)
    setups = Setups()
    codec = Mistakes(jpeg_quality=JPEG_QUALITY) if row.endswith("mjpeg") else NO_MISTAKES
    camera = SimulatedCamera(world.layout.cameras[0], world, 0, setups, codec)
    camera.grab()  # the camera's pixel rays, computed once
    images, render_s = {}, []
    for i, pose in enumerate(rig_poses):
        setups.begin(pose_setup(i))
        world.place_rig(pose)
        t0 = time.perf_counter()
        images[("cam0", f"pose/{i:04d}")] = camera.grab().image
        render_s.append(time.perf_counter() - t0)
    rig = world.rig
    board = Checkerboard(rig.corners_x, rig.corners_y, rig.square_m)
    cal = calibrate_images(images, ["cam0"], board)
    fitted = cal.intrinsics["cam0"]
    true_f = world.layout.cameras[0].K[0, 0]
    errors = [view.corners_px - world.layout.cameras[0].project(
                  rig_poses[int(step.split("/")[1])].apply(world.physical_rig.corner_points()))
              for (_, step), view in cal.views.items()]
    return {"row": row, "seed": seed, "poses": poses, "views": fitted.n_views,
            "rms_px": fitted.rms_px,
            "corner_error_px": float(np.sqrt(np.mean(np.sum(np.vstack(errors) ** 2, axis=1)))),
            "noise_estimate_px": fitted.noise.sigma_px,
            "true_noise_px": float(np.std(np.vstack(errors) - np.vstack(errors).mean(axis=0))),
            "focal_error_px": float(fitted.K[0, 0] - true_f),
            "render_s": float(np.mean(render_s))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=8)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--rows", nargs="+", default=list(ROWS), choices=ROWS)
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "camera_effects.json")
    args = parser.parse_args()
    results = [measure(row, args.poses, seed) for row in args.rows for seed in args.seeds]
    print("| effect | seed | views | corner RMS (px) | corner error (px) | noise estimate "
          "(px) | true noise (px) | focal error (px) | render (s) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in results:
        print(f"| {r['row']} | {r['seed']} | {r['views']} | {r['rms_px']:.4f} | "
              f"{r['corner_error_px']:.4f} | {r['noise_estimate_px']:.4f} | "
              f"{r['true_noise_px']:.4f} | {r['focal_error_px']:+.3f} | {r['render_s']:.3f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2))
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
