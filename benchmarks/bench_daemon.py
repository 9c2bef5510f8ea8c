"""The daemon's capture throughput on the simulated world, and its CPU share at real time.

Starts `micam daemon` in a subprocess on the simulated world (72-microphone sphere, 3 cameras,
MLS order 14 at 96 kS/s, ipc sockets in a temporary directory), drives a session through the
client as fast as the daemon accepts captures, and measures:

- poses per minute: pose captures only (6 bursts and 3 images each), wall-clock;
- CPU share at the real-time rate: the daemon process's CPU seconds (user + system, from
  /proc) per second of recorded 72-channel audio at 96 kS/s. On the simulated world this
  includes simulating the boards and rendering the cameras, so a second figure subtracts the
  CPU time of the bare sequencer on the same world (measured in this process): the daemon's
  own overhead (quality checks, events, sockets, state journal).

The daemon's log goes to $TMPDIR/micam-bench-daemon.log.

    .venv/bin/python benchmarks/bench_daemon.py [--poses 10]

Prints the figures and writes them as JSON to benchmarks/results/daemon.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _figures import report

from acquisition.daemon.client import DaemonClient
from acquisition.sequencer import CaptureSequencer, Progress
from acquisition.contracts.session import SessionWriter
from sim.capture import SimulationOptions, build_simulated_capture

REPO = Path(__file__).resolve().parents[1]
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of process `pid` so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def start_daemon(tmp: Path, options: SimulationOptions) -> tuple[subprocess.Popen, socket.socket]:
    config = tmp / "daemon.toml"
    world = "\n".join(f"{k} = {json.dumps(v)}" for k, v in options.model_dump().items()
                      if k in ("array", "poses", "mls_order", "seed", "backend"))
    config.write_text(f'session_root = "{tmp}/sessions"\n[sockets]\ncontrol = "ipc://{tmp}/c"\n'
                      f'events = "ipc://{tmp}/e"\n[simulation]\n{world}\n')
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp / "notify"))
    notify.settimeout(60)
    env = {**os.environ, "NOTIFY_SOCKET": str(tmp / "notify")}
    log = (Path(tempfile.gettempdir()) / "micam-bench-daemon.log").open("w")
    proc = subprocess.Popen([sys.executable, "-m", "micam.cli", "daemon", "--config",
                             str(config)], env=env, cwd=REPO, stdout=log, stderr=log)
    for _ in range(100):
        if b"READY=1" in notify.recv(4096):
            return proc, notify
    raise RuntimeError("the daemon never reported READY=1")


def capture(client: DaemonClient) -> None:
    number = client.request("capture")["number"]
    status = client.wait_until(lambda s: s.session is None or (
        s.last_capture is not None and s.last_capture.number >= number), 120.0, interval_s=0.02)
    if status.session is not None and status.last_capture.outcome != "complete":
        raise RuntimeError(f"capture failed: {status.last_capture}")


def sequencer_cpu_per_pose(options: SimulationOptions, tmp: Path) -> float:
    """CPU seconds per pose of the bare sequencer (simulated hardware + session store)."""
    sim = build_simulated_capture(options)
    writer = SessionWriter.create(tmp / "bare", capture=sim.config.model_dump(mode="json"))
    marks: list[float] = []

    def on_progress(p: Progress) -> None:
        if p.step.startswith("pose/") or p.step == "refmic":
            marks.append(time.process_time())

    CaptureSequencer(sim.config, sim.group, sim.cameras, sim.operator, writer,
                     on_progress=on_progress).run()
    return (marks[-1] - marks[0]) / (len(marks) - 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=10)
    parser.add_argument("--array", default="sphere72")
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "daemon.json")
    args = parser.parse_args()
    options = SimulationOptions(array=args.array, poses=args.poses, mls_order=14)

    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        proc, notify = start_daemon(tmp, options)
        try:
            with DaemonClient(f"ipc://{tmp}/c", timeout_s=30) as client:
                session = client.request("session.start")["session"]
                for _ in range(session["steps_total"] - args.poses):  # references and refmic
                    capture(client)
                wall0, cpu0 = time.perf_counter(), cpu_seconds(proc.pid)
                for _ in range(args.poses):
                    capture(client)
                wall, cpu = time.perf_counter() - wall0, cpu_seconds(proc.pid) - cpu0
        finally:
            proc.terminate()
            proc.wait(60)
            notify.close()
        bare_cpu_per_pose = sequencer_cpu_per_pose(options, tmp)

    sim = build_simulated_capture(options)
    config = sim.config
    n_speakers = len(config.speakers)
    audio_s = args.poses * n_speakers * config.burst.n_samples / config.sample_rate_hz
    figures = {
        "array": args.array,
        "channels": len(config.columns),
        "cameras": len(config.cameras),
        "sample_rate_hz": config.sample_rate_hz,
        "mls_order": config.burst.mls_order,
        "poses": args.poses,
        "poses_per_minute": round(60 * args.poses / wall, 1),
        "seconds_per_pose": round(wall / args.poses, 3),
        "audio_seconds_recorded": round(audio_s, 3),
        "cpu_share_at_real_time": round(cpu / audio_s, 3),
        "daemon_overhead_cpu_share": round((cpu - args.poses * bare_cpu_per_pose) / audio_s, 3),
        "bare_sequencer_cpu_s_per_pose": round(bare_cpu_per_pose, 3),
        "daemon_cpu_s_per_pose": round(cpu / args.poses, 3),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
    }
    report(figures, args.out)


if __name__ == "__main__":
    main()
