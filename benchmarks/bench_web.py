"""What the operator's page costs the daemon, and how late the page sees the daemon's events.

A daemon on the simulated world (scatter48, one camera) with one calibration worker runs the
same scripted capture twice: without `micam web`, then with `micam web` and `--browsers`
headless Chromium pages connected (previews flowing, status polled every second). For each
run it measures the daemon's CPU time (user + system, /proc) over two windows: while it waits
for a pose (`--idle` seconds, the previews' cost) and while the session is captured. With the
page, every browser records each event's delay from the daemon's time stamp (`time_utc`,
taken when it publishes) to its arrival in the page's script: p50 and p99 over all events and
browsers. The simulated camera renders one preview per set-up (sim.cameras), so on real
cameras add the cost of grabbing one frame per preview.

    .venv/bin/python benchmarks/bench_web.py [--poses 6] [--idle 10] [--browsers 1]

Prints the figures and writes benchmarks/results/web.json.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
from _figures import report

from micam.demo_loop import Loop
from micam.web.testing import Chromium, WebProcess

RESULTS = Path(__file__).with_name("results") / "web.json"
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of process `pid` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def capture_all(loop: Loop, poses: int) -> None:
    """Capture every step of a session of `poses` poses, waiting for each."""
    with loop.client() as client:
        client.request("session.start", poses=poses)
        for _ in range(client.status().session.steps_total * 3):
            number = client.request("capture")["number"]
            status = client.wait_until(lambda s, n=number: s.session is None or (
                s.last_capture is not None and s.last_capture.number >= n), 120,
                interval_s=0.05)
            if status.session is None:
                return
    raise RuntimeError("the session did not close")


def run(poses: int, idle_s: float, browsers: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp, Loop(Path(tmp), poses + 1, array="scatter48",
                                                    mls_order=9, seed=3) as loop:
        web = pages = None
        if browsers:
            web = WebProcess(loop.control, Path(tmp) / "web.log")
            pages = [Chromium(width=1200, height=900) for _ in range(browsers)]
            for page in pages:
                page.driver.get(web.url + "/")
                page.wait("window.micam.snapshots > 0")
        try:
            with loop.client() as client:  # wait for a pose: the first pose's instruction
                client.request("session.start", poses=poses)
                for _ in range(7):
                    number = client.request("capture")["number"]
                    client.wait_until(lambda s, n=number: s.last_capture is not None
                                      and s.last_capture.number >= n, 60, interval_s=0.05)
                time.sleep(2.0)  # the page's preview lease and first looks settle
                before, start = cpu_s(loop.daemon_pid), time.monotonic()
                time.sleep(idle_s)
                idle = (cpu_s(loop.daemon_pid) - before) / (time.monotonic() - start)
                client.request("session.abort")
                client.wait_until(lambda s: s.session is None, 60)
            if pages:
                for page in pages:
                    page.js("window.micam.latencies = []")
            before, start = cpu_s(loop.daemon_pid), time.monotonic()
            capture_all(loop, poses)
            wall = time.monotonic() - start
            capturing = (cpu_s(loop.daemon_pid) - before) / wall
            latencies = []
            if pages:
                time.sleep(1.0)
                for page in pages:
                    latencies += page.js("return window.micam.latencies")
        finally:
            for page in pages or []:
                page.close()
            if web is not None:
                web.stop()
    figures = {"idle_cpu_share": round(idle, 4), "capture_cpu_share": round(capturing, 4),
               "capture_wall_s": round(wall, 2)}
    if latencies:
        figures.update(events=len(latencies),
                       latency_p50_ms=round(float(np.percentile(latencies, 50)), 1),
                       latency_p99_ms=round(float(np.percentile(latencies, 99)), 1))
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, default=6)
    parser.add_argument("--idle", type=float, default=10.0, metavar="S")
    parser.add_argument("--browsers", type=int, default=1)
    args = parser.parse_args()
    without = run(args.poses, args.idle, 0)
    with_page = run(args.poses, args.idle, args.browsers)
    figures = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "poses": args.poses, "browsers": args.browsers,
        "daemon_cpu_waiting_without_page": without["idle_cpu_share"],
        "daemon_cpu_waiting_with_page": with_page["idle_cpu_share"],
        "daemon_cpu_capturing_without_page": without["capture_cpu_share"],
        "daemon_cpu_capturing_with_page": with_page["capture_cpu_share"],
        "page_adds_waiting_core_share": round(with_page["idle_cpu_share"]
                                              - without["idle_cpu_share"], 4),
        "page_adds_capturing_core_share": round(with_page["capture_cpu_share"]
                                                - without["capture_cpu_share"], 4),
        "events_to_page": with_page.get("events"),
        "event_to_page_p50_ms": with_page.get("latency_p50_ms"),
        "event_to_page_p99_ms": with_page.get("latency_p99_ms"),
    }
    report(figures, RESULTS, width=36)


if __name__ == "__main__":
    main()
