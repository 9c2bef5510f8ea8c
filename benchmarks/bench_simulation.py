"""How long a simulated capture takes, per step kind and per pose.

Runs the real capture sequencer on the simulated world (72-microphone sphere, 3 cameras, MLS
order 14 at 96 kS/s) into a temporary directory, prints the figures and writes them as JSON to
benchmarks/results/simulation.json.

    .venv/bin/python benchmarks/bench_simulation.py [--poses 20]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from acquisition.sequencer import CaptureSequencer, Progress
from acquisition.contracts.session import SessionWriter
from sim.capture import SimulationOptions, build_simulated_capture


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=20)
    parser.add_argument("--array", default="sphere72")
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "simulation.json")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        sim = build_simulated_capture(SimulationOptions(array=args.array, poses=args.poses))
        setup_s = time.perf_counter() - t0
        writer = SessionWriter.create(Path(tmp) / "s", capture=sim.config.model_dump(mode="json"))
        durations: dict[str, list[float]] = {"reference": [], "refmic": [], "pose": []}
        last = [time.perf_counter()]

        def on_progress(p: Progress) -> None:
            now = time.perf_counter()
            durations[p.step.split("/")[0]].append(now - last[0])
            last[0] = now

        seq = CaptureSequencer(sim.config, sim.group, sim.cameras, sim.operator, writer,
                               on_progress=on_progress)
        t1 = time.perf_counter()
        seq.run()
        capture_s = time.perf_counter() - t1
        size_mb = sum(f.stat().st_size for f in (Path(tmp) / "s").rglob("*")) / 1e6

    per_pose = durations["pose"]
    figures = {
        "array": args.array,
        "poses": args.poses,
        "channels": len(sim.config.columns),
        "cameras": len(sim.config.cameras),
        "samples_per_recording": sim.config.burst.n_samples,
        "setup_s": round(setup_s, 3),
        "capture_s": round(capture_s, 3),
        "per_pose_mean_s": round(sum(per_pose) / len(per_pose), 4),
        "per_pose_max_s": round(max(per_pose), 4),
        "per_reference_mean_s": round(sum(durations["reference"]) / 6, 4),
        "session_mb": round(size_mb, 1),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
    }
    for key, value in figures.items():
        print(f"{key:24s} {value}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(figures, indent=2))
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
