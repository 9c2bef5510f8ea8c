"""The realistic lab's error budget (issue 12): each systematic effect alone and all together,
calibrated with the real lab's model off (the first wave's calibration) and on, against the
simulated truth.

For every row a 72-microphone sphere session is simulated at 0.6-1.2 m (kept with --keep, so a
second run only calibrates), then calibrated twice:

- model off: the matched TOF correlation, no speaker offsets, no print scale, no microphone
  delays, one c for the session, the air sensor ignored;
- model on: micam's default (compact TOFs, all of those unknowns, the air sensor's c).

Columns: mean and max microphone error against the true capsule positions, the error of the
session's mean c, the share of microphones within 2 sigma (3-D, 95.4 %) of their reported
covariance, the same for their errors relative to the array's common motion and that motion's
chi-square (7 degrees of freedom; calibration.checks.coverage says why the plain share is a poor
judge of one session), the joint fit's own bound (E|e| of its covariance: the Cramer-Rao bound of
the model with the added unknowns, at the noise levels it estimated) and the run time of the
whole calibration with the model on, and the weighting its times of flight took (with the
echo ratio that chose it, calibration.pipeline.FREE_FIELD_ECHO_RATIO).

Every effect row has the lab's air sensor too (a lab has one; without any absolute length
the metric scale and c are confounded, which the "all, no air sensor" row shows).

    .venv/bin/python benchmarks/bench_real_lab.py [--poses 20] [--seeds 1] [--keep DIR]
    .venv/bin/python benchmarks/bench_real_lab.py --rows all --poses 30 --seeds 1 2 3 4 5
    .venv/bin/python benchmarks/bench_real_lab.py --rows all --poses 140 --seeds 1
    .venv/bin/python benchmarks/bench_real_lab.py --rows all ideal --seeds 1 2 --workers 2

Each cell (a row and a seed) is a task on a Dask cluster with --workers N (a local one) or
--scheduler ADDRESS (whose workers must see --keep at the same path), as `micam study` runs
its bands (micam.cluster); the same numbers as one after another in one process with one
BLAS thread, but for the run times.

Printed as a markdown table, written as JSON to benchmarks/results/real_lab.json (or --out).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from micam.cluster import add_cluster_options, cluster_map
from micam.simulated import record_simulated_session
from calibration.checks.coverage import coverage
from calibration.solve.crlb import expected_error_norm
from calibration.pipeline import CalibrationOptions, calibrate
from sim.capture import SimulationOptions
from sim.lab import EFFECTS

MAGNITUDES = {
    "ideal": "none",
    "acoustic-centres": "1.5-4 mm in front, -0.2 mm/octave",
    "rig-tolerance": "0.3 mm per axis per speaker",
    "print-scale": "0.05-0.1 % larger or smaller",
    "mic-responses": "0.47 us RMS group delay, 1 dB gain",
    "air-drift": "0.4 K over the session",
    "room": "7 image sources, absorption 0.3 (table 0.1)",
    "ambient-noise": "30 mV below 80 Hz",
    "directivity": "26 mm baffled piston",
    "driver-delays": "2 us RMS per speaker",
    "sensor-noise": "shot + 5 e- read noise, gain 16",
    "fixed-pattern": "PRNU 1 %, DSNU 4 e-",
    "defocus": "f/2 focused at 1.2 m",
    "lens-distortion": "13 % barrel, tangential",
    "vignetting": "cos^4, 0.37 at the corners",
    "lighting": "a lamp and a highlight",
    "board-bow": "0.5 mm sag",
    "gamma": "1/2.2, 8 bits",
    "all": "every effect above",
    "all, no air sensor": "every effect, no absolute length",
}
ROWS = ["ideal", *[e for e in EFFECTS if e != "air-sensor"], "all", "all, no air sensor"]
MODEL_OFF = CalibrationOptions(weighting="matched", speaker_offsets=False, print_scale=False,
                               mic_delay_std_s=None, speed_of_sound_per_pose=False,
                               air_sensor=False, responses=False)


def simulation_options(row: str, poses: int, seed: int) -> SimulationOptions:
    common = {"poses": poses, "seed": seed, "distance_m": (0.6, 1.2)}
    if row == "ideal":
        return SimulationOptions(**common)
    if row == "all":
        return SimulationOptions(lab="realistic", **common)
    if row == "all, no air sensor":
        return SimulationOptions(lab="realistic", without_effects=("air-sensor",), **common)
    return SimulationOptions(effects=(row, "air-sensor"), **common)


def session(directory: Path, row: str, poses: int, seed: int) -> tuple[Path, dict]:
    name = f"{row.replace(', ', '-').replace(' ', '-')}-{poses}p-s{seed}"
    path = directory / name
    if (path / "truth.json").is_file() and json.loads(
            (path / "manifest.json").read_text())["status"] == "complete":
        return path, json.loads((path / "truth.json").read_text())
    return path, record_simulated_session(path, simulation_options(row, poses, seed))


def figures(path: Path, truth: dict, options: CalibrationOptions) -> dict:
    t0 = time.perf_counter()
    run = calibrate(path, options)
    seconds = time.perf_counter() - t0
    true = {m["id"]: np.array(m["position_m"]) for m in truth["microphones"]}
    ids = run.data.mic_ids
    error = run.solution.positions_m - np.array([true[int(i)] for i in ids])
    cov = run.solution.covariance_m2
    z = np.einsum("mi,mij,mj->m", error, np.linalg.inv(cov), error)
    norm = np.linalg.norm(error, axis=1)
    out = {
        "mean_mic_error_mm": round(1e3 * float(norm.mean()), 4),
        "max_mic_error_mm": round(1e3 * float(norm.max()), 4),
        "speed_of_sound_error_m_s": round(run.result.speed_of_sound_m_s
                                          - truth["speed_of_sound_m_s"], 4),
        "within_2_sigma": round(float(np.mean(z < chi2.ppf(0.9545, 3))), 3),
        "bound_mean_error_mm": round(1e3 * float(np.mean(expected_error_norm(cov))), 4),
        "calibration_s": round(seconds, 2),
        "weighting": run.result.tof_quality.weighting,
        "echo_ratio": run.result.tof_quality.echo_ratio,
    }
    if run.bundle is not None and np.isfinite(error).all():
        mics = run.bundle.parameter_slices["microphones"]
        split = coverage(error, run.bundle.covariance[mics, mics], run.solution.positions_m)
        out.update(common_motion_chi2=round(split.common_chi2, 2),
                   common_motion_p=round(split.common_p, 3),
                   relative_within_2_sigma=round(split.relative_within_2_sigma, 3))
    return out


def budget_row(directory: Path, row: str, poses: int, seed: int) -> dict:
    """One cell of the budget: the row's session (simulated, or kept from an earlier run)
    calibrated with the model off and on."""
    path, truth = session(directory, row, poses, seed)
    return {"row": row, "magnitude": MAGNITUDES[row], "poses": poses, "seed": seed,
            "off": figures(path, truth, MODEL_OFF),
            "on": figures(path, truth, CalibrationOptions())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", nargs="+", default=ROWS, choices=ROWS, metavar="ROW",
                        help=f"which rows (default all of: {', '.join(ROWS)})")
    parser.add_argument("--poses", type=int, default=20)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep the simulated sessions here (and reuse them)")
    add_cluster_options(parser, "the cells (row x seed)", "--keep")
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "real_lab.json")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp, \
            cluster_map("real-lab", args.scheduler, args.workers) as mapper:
        directory = (args.keep or Path(tmp)).absolute()
        directory.mkdir(parents=True, exist_ok=True)
        jobs = [(directory, row, args.poses, seed) for row in args.rows for seed in args.seeds]
        for entry in (mapper(budget_row, jobs) if mapper else (budget_row(*j) for j in jobs)):
            results.append(entry)
            on, off = entry["on"], entry["off"]
            print(f"| {entry['row']} | {entry['magnitude']} | {entry['seed']} "
                  f"| {off['mean_mic_error_mm']:.3f} "
                  f"| {on['mean_mic_error_mm']:.3f} ({on['max_mic_error_mm']:.3f}) "
                  f"| {off['speed_of_sound_error_m_s']:+.3f} "
                  f"| {on['speed_of_sound_error_m_s']:+.3f} | {on['within_2_sigma']:.2f} "
                  f"| {on.get('relative_within_2_sigma', np.nan):.2f} "
                  f"| {on.get('common_motion_chi2', np.nan):.1f} "
                  f"| {on['bound_mean_error_mm']:.3f} | {on['calibration_s']:.1f} "
                  f"| {on['weighting']} ({on['echo_ratio']:.3f}) |",
                  flush=True)
    report = {"results": results, "machine": {"cpus": os.cpu_count(),
                                              "python": platform.python_version()}}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    print(f"columns: row | magnitude | seed | mean error off (mm) | on (max) | c error off "
          f"(m/s) | on | within 2 sigma | relative to the common motion | common motion chi2 (7 dof) "
          f"| bound (mm) | calibration (s) | weighting (echo ratio)\nwritten to {args.out}")


if __name__ == "__main__":
    main()
