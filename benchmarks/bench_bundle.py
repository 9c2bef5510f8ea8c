"""The joint fit (optical-acoustic bundle adjustment, issue 8): run time and accuracy against
the truth, camera frozen beside joint.

Sessions (default noise, rig at 0.6-1.0 m): the 72-microphone sphere with 30 poses (three
cameras, the side ones sharing views with camera 0, so the stereo extrinsics are refined
too), the planar 64-microphone array with 30 poses, and the sphere with 140 poses for the run
time (goal: under 10 s on a 2-core machine). Each is simulated once into --sessions and reused.
Printed, and written as JSON to benchmarks/results/bundle.json.

    .venv/bin/python benchmarks/bench_bundle.py [--sessions DIR] [--only sphere72-30 ...]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

from micam.simulated import record_simulated_session
from calibration.pipeline import (
    CalibrationOptions,
    fit_joint,
    joint_measurements,
    measure,
    solve,
)
from calibration.result import compare_with_truth
from calibration.result_assembly import _assemble
from sim.capture import SimulationOptions

CASES = {
    "sphere72-30": SimulationOptions(array="sphere72", poses=30, seed=1),
    "planar64-30": SimulationOptions(array="planar64", poses=30, seed=1),
    "sphere72-140": SimulationOptions(array="sphere72", poses=140, seed=1),
}
GOALS = {"mean_mic_error_mm": 0.2, "max_focal_error_percent": 0.03,
         "abs_speed_of_sound_error_m_s": 0.02, "max_latency_error_us": 0.1}
"""The issue's 'done when' figures for the joint fit (30 poses)."""


def session(directory: Path, name: str, options: SimulationOptions) -> Path:
    """The case's session, simulated into `directory` unless it is already there."""
    path = directory / f"{options.array}-{options.poses}-seed{options.seed}"
    if not (path / "truth.json").is_file():
        print(f"simulating {name} into {path} ...", flush=True)
        record_simulated_session(path, options)
    return path


def figures(errors: dict[str, float]) -> dict[str, float]:
    """The comparison with the truth in the units the goals are stated in."""
    out = {"mean_mic_error_mm": 1e3 * errors["mean_mic_error_m"],
           "max_mic_error_mm": 1e3 * errors["max_mic_error_m"],
           "abs_speed_of_sound_error_m_s": abs(errors["speed_of_sound_error_m_s"]),
           "max_focal_error_percent": 100 * errors["max_focal_error_rel"],
           "max_latency_error_us": 1e6 * errors["max_latency_error_s"]}
    return {k: round(v, 4) for k, v in out.items()}


def bench(path: Path) -> dict:
    """Frozen and joint solutions of one session, the joint fit timed on its own."""
    options = CalibrationOptions()
    truth = json.loads((path / "truth.json").read_text())
    m = measure(path, options)
    frozen = solve(m, options)
    t0 = time.perf_counter()
    bundle = fit_joint(m, frozen, options)
    joint_s = time.perf_counter() - t0
    joint_m, joint = joint_measurements(m, bundle, frozen, options)
    frozen_result = _assemble(m, frozen, options, {})
    joint_result = _assemble(joint_m, joint, options, {})
    n_cameras = len(m.cameras.intrinsics)
    return {
        "poses": len(m.located),
        "sources": len(m.located) * m.data.n_speakers,
        "microphones": len(m.data.mic_ids),
        "cameras": n_cameras,
        "board_views": len(m.cameras.views),
        "unknowns": int(bundle.covariance.shape[0]),
        "joint_fit_s": round(joint_s, 2),
        "iterations": bundle.iterations,
        "sigmas": {k: round(v, 4) for k, v in bundle.sigmas.items()},
        "chi2_per_dof": round(bundle.chi2_per_dof, 3),
        "outliers": {"corners": int(bundle.corner_outliers.sum()),
                     "tofs": int(bundle.tof_outliers.sum())},
        "camera_frozen": figures(compare_with_truth(frozen_result, truth)),
        "joint": figures(compare_with_truth(joint_result, truth)),
        "joint_std": {
            "speed_of_sound_m_s": round(bundle.std.speed_of_sound_m_s, 4),
            "focal_percent": round(100 * float((bundle.std.intrinsics[:, :2]
                                                / bundle.state.intrinsics[:, :2]).max()), 4),
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=Path, default=Path("/tmp/micam-bench-bundle"),
                        help="where the simulated sessions are kept between runs")
    parser.add_argument("--only", nargs="+", choices=sorted(CASES), default=list(CASES))
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "bundle.json")
    args = parser.parse_args()
    args.sessions.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in args.only:
        results[name] = bench(session(args.sessions, name, CASES[name]))
        r = results[name]
        print(f"{name}: {r['sources']} sources, {r['cameras']} cameras, {r['unknowns']} "
              f"unknowns; joint fit {r['joint_fit_s']:.2f} s ({r['iterations']} iterations)")
        for key, goal in GOALS.items():
            print(f"  {key:32s} frozen {r['camera_frozen'][key]:9.4f}   joint "
                  f"{r['joint'][key]:9.4f}   (goal <= {goal})")
    doc = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
           "goals_joint_30_poses": GOALS, "cases": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"written: {args.out}")


if __name__ == "__main__":
    main()
