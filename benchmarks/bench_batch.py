"""A batch of calibrations on a LocalCluster of worker processes against the serial loop.

N small simulated sessions (scatter48, a few poses) are calibrated twice: one after another in
this process (`micam.batch.cells.run_cell`, what a loop over `micam calibrate` does without
its report), and as a batch (`micam.batch.run_batch`) on a LocalCluster of `--workers`
processes of one thread each, configured as `micam batch` configures its own and started
beforehand (its start-up is timed apart). Both include the imports of the calibration, once
per process. The per-task overhead is what the batch
spends beyond its tasks' own run time: (batch wall time x workers - sum of task times) / N.

    .venv/bin/python benchmarks/bench_batch.py [--sessions 20] [--workers 2] [--poses 4]

Prints the figures and writes benchmarks/results/batch.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from micam.batch import run_batch
from micam.batch.cells import plan_cells, portable_options, run_cell
from micam.cluster import local_cluster_config
from micam.commands.calibrate import calibration_options
from micam.simulated import record_simulated_session
from sim.capture import SimulationOptions

RESULTS = Path(__file__).with_name("results") / "batch.json"


def _sessions(root: Path, n: int, poses: int, mls_order: int) -> list[Path]:
    made = []
    for seed in range(n):
        path = root / f"s{seed:03d}"
        record_simulated_session(path, SimulationOptions(array="scatter48", poses=poses,
                                                         mls_order=mls_order, seed=seed))
        made.append(path)
    return made


def main() -> None:
    import dask
    from distributed import LocalCluster

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--poses", type=int, default=4)
    parser.add_argument("--mls-order", type=int, default=9)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t = time.perf_counter()
        sessions = _sessions(root / "sessions", args.sessions, args.poses, args.mls_order)
        print(f"{args.sessions} sessions simulated in {time.perf_counter() - t:.1f} s",
              flush=True)
        options = portable_options(calibration_options())
        t = time.perf_counter()
        serial = [run_cell(cell, options) for cell in plan_cells(sessions, root / "serial")]
        serial_s = time.perf_counter() - t
        assert all(r.status == "ok" for r in serial), [r.message for r in serial]
        print(f"serial loop: {serial_s:.1f} s", flush=True)
        t = time.perf_counter()
        with dask.config.set(local_cluster_config(retries=2)), \
                LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                             dashboard_address=None) as cluster:
            startup_s = time.perf_counter() - t
            t = time.perf_counter()
            outcome = run_batch(sessions, root / "batch", scheduler=cluster.scheduler_address,
                                progress=False)
            batch_s = time.perf_counter() - t
        assert not outcome.failed, [r.message for r in outcome.failed]
        task_s = sum(r.seconds for r in outcome.rows)
    row = {
        "sessions": args.sessions, "workers": args.workers, "poses": args.poses,
        "mls_order": args.mls_order, "cpus": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "serial_s": round(serial_s, 2), "cluster_startup_s": round(startup_s, 2),
        "batch_s": round(batch_s, 2), "speed_up": round(serial_s / batch_s, 2),
        "speed_up_with_startup": round(serial_s / (batch_s + startup_s), 2),
        "serial_task_mean_s": round(sum(r.seconds for r in serial) / args.sessions, 3),
        "batch_task_mean_s": round(task_s / args.sessions, 3),
        "overhead_per_task_s": round((batch_s * args.workers - task_s) / args.sessions, 3),
    }
    print(f"batch on {args.workers} workers: {batch_s:.1f} s (+ {startup_s:.1f} s to start the "
          f"cluster): speed-up {row['speed_up']}x ({row['speed_up_with_startup']}x with the "
          f"start-up); task mean {row['batch_task_mean_s']} s on a worker against "
          f"{row['serial_task_mean_s']} s serially; overhead {row['overhead_per_task_s']} s "
          f"per task; load average {row['load_average']}")
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps({"machine": platform.platform(), "cpu": platform.processor(),
                                   "rows": [row]}, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
