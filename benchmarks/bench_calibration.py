"""Run time and accuracy of the calibration pipeline on simulated sessions (issue 3).

For each pose count (default 20 and 140: 120 and 840 sources), a 72-microphone sphere session
at 0.6-1.0 m with default noise is simulated, then calibrated by micam's solver and by the
paper's method on the same measurements. Printed, and written as JSON to
benchmarks/results/calibration.json: time per stage, mean / max microphone error against the
truth, speed-of-sound error, and the Cramer-Rao bound of the same sources and noise.

    .venv/bin/python benchmarks/bench_calibration.py [--poses 20 140] [--keep DIR]
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

from micam.simulated import record_simulated_session
from calibration.solve.crlb import expected_error_norm, joint_crlb
from calibration.pipeline import (
    CalibrationOptions,
    _rig_sources,
    fit_joint,
    joint_measurements,
    measure,
    solve,
)
from calibration.plan import board_indices
from sim.capture import SimulationOptions


def _errors(solution, mic_ids, truth: dict) -> dict[str, float]:
    true = {m["id"]: m["position_m"] for m in truth["microphones"]}
    err = np.linalg.norm(solution.positions_m - np.array([true[int(i)] for i in mic_ids]),
                         axis=1)
    return {"mean_mic_error_mm": round(1e3 * float(err.mean()), 4),
            "max_mic_error_mm": round(1e3 * float(err.max()), 4),
            "speed_of_sound_error_m_s": round(solution.speed_of_sound_m_s
                                              - truth["speed_of_sound_m_s"], 4)}


def bench(poses: int, directory: Path) -> dict:
    session = directory / f"sphere72-{poses}"
    t0 = time.perf_counter()
    if (session / "truth.json").is_file():  # kept from an earlier run (--keep)
        truth = json.loads((session / "truth.json").read_text())
    else:
        truth = record_simulated_session(session, SimulationOptions(poses=poses, seed=poses))
    simulate_s = time.perf_counter() - t0
    m = measure(session)
    figures: dict = {"poses": poses, "sources": poses * m.data.n_speakers,
                     "simulate_s": round(simulate_s, 2), "stages_s": dict(m.timings_s)}
    for method in ("micam", "paper"):
        t1 = time.perf_counter()
        sol = solve(m, CalibrationOptions(method=method))
        figures[method] = {"solver_s": round(time.perf_counter() - t1, 3),
                           **_errors(sol, m.data.mic_ids, truth)}
        if method == "micam":
            frozen = sol
    t2 = time.perf_counter()
    options = CalibrationOptions()
    _, joint = joint_measurements(m, fit_joint(m, frozen, options), frozen, options)
    figures["micam_joint"] = {"joint_fit_s": round(time.perf_counter() - t2, 3),
                              **_errors(joint, m.data.mic_ids, truth)}
    # The joint fit's own bound: E|e| of its covariance (the inverse Fisher information of the
    # full model, intrinsics unknown, at the estimate, with the noise levels it estimated).
    joint_bound_mm = 1e3 * float(np.mean(expected_error_norm(joint.covariance_m2)))
    figures["micam_joint"]["bound_mean_error_mm"] = round(joint_bound_mm, 4)
    figures["micam_joint"]["efficiency"] = round(
        figures["micam_joint"]["mean_mic_error_mm"] / joint_bound_mm, 2)
    true = {mic["id"]: mic["position_m"] for mic in truth["microphones"]}
    mics = np.array([true[int(i)] for i in m.data.mic_ids])
    n_mic = len(m.data.mic_ids)
    sources = _rig_sources(m.data, m.speakers, np.arange(len(m.located)),
                           np.arange(m.data.n_speakers))
    bound = joint_crlb(mics, sources, truth["speed_of_sound_m_s"],
                       m.tofs.std_s[m.located].reshape(-1, n_mic), fit_speed_of_sound=False,
                       latency="per_board", board_of_mic=board_indices(m.data)[1],
                       reference_board=None, pose_errors=True)
    crlb_mm = 1e3 * float(np.mean(expected_error_norm(bound.mic_covariance_m2)))
    figures["crlb_mean_error_mm"] = round(crlb_mm, 4)
    figures["efficiency_camera_frozen"] = round(figures["micam"]["mean_mic_error_mm"] / crlb_mm,
                                                2)
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, nargs="+", default=[20, 140])
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep the simulated sessions in this directory")
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "calibration.json")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        directory = args.keep or Path(tmp)
        directory.mkdir(parents=True, exist_ok=True)
        runs = [bench(n, directory) for n in args.poses]
    report = {"runs": runs, "machine": {"cpus": os.cpu_count(),
                                        "python": platform.python_version()}}
    print(json.dumps(report, indent=1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
