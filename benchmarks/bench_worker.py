"""Time from the last pose captured to the final calibration published, through the whole loop.

The daemon runs on the simulated world (sphere72, 3 cameras) with one `micam worker`; the
capture is scripted through the `micam` commands (micam.demo_loop), so live
calibrations run during the capture as they would for an operator. The clock starts when the
command that captured the last pose returns (the session is closed and the final job queued)
and stops when the `calibration` event arrives: fetching the last files and the journal,
waiting for a live job still running, and the full calibration (joint fit included).

    .venv/bin/python benchmarks/bench_worker.py [--poses 20 140] [--mls-order 12]

Prints a table and writes benchmarks/results/worker.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

from micam.demo_loop import Loop, scripted_capture, wait_final

RESULTS = Path(__file__).with_name("results") / "worker.json"


def measure(poses: int, mls_order: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp, Loop(Path(tmp), poses,
                                                    mls_order=mls_order) as loop, \
            loop.client() as client:
        stream = client.subscribe()
        try:
            start = time.monotonic()
            _, last_pose = scripted_capture(loop, poses, show=False)
            event = wait_final(stream, 3600.0)
            published = time.monotonic()
        finally:
            stream.close()
    return {"poses": poses, "mls_order": mls_order,
            "capture_s": round(last_pose - start, 1),
            "last_pose_to_result_s": round(published - last_pose, 2),
            "mean_std_mm": round(event.mean_std_m * 1e3, 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, nargs="+", default=[20, 140])
    parser.add_argument("--mls-order", type=int, default=12)
    args = parser.parse_args()
    rows = []
    for poses in args.poses:
        row = measure(poses, args.mls_order)
        rows.append(row)
        print(f"{poses:4d} poses: capture {row['capture_s']:7.1f} s, last pose -> final result "
              f"{row['last_pose_to_result_s']:7.2f} s (mean std {row['mean_std_mm']} mm)",
              flush=True)
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps({"machine": platform.platform(), "cpu": platform.processor(),
                                   "rows": rows}, indent=1) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
