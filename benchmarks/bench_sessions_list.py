"""`sessions.list` over many stored sessions, and whether indexing them holds up the daemon.

Fills a session root with N sessions (default 10 000: copies of one simulated session's
journal, each with its own session id; the listing reads journals only), starts `micam daemon`
on it in a subprocess (the simulated world, ipc sockets in a temporary directory) and measures:

- first start: how long the background index takes to read every journal, and the round
  trip of `ping` meanwhile (the loop thread is never the one reading: median and worst);
- `sessions.list` once indexed: the round trip of the raw reply (send to last byte received,
  the daemon's answer) and, apart, how long this client takes to parse it;
- a restart: how long until the index, read back from SESSION_ROOT.index.json, is complete
  (only the journals' sizes and times are checked).

    .venv/bin/python benchmarks/bench_sessions_list.py [--sessions 10000] [--poses 5]

Prints the figures and writes them as JSON to benchmarks/results/sessions_list.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zmq
from _figures import report

from acquisition.contracts.protocol import Reply
from micam.simulated import record_simulated_session
from sim.capture import SimulationOptions

REPO = Path(__file__).resolve().parents[1]


def fill_root(root: Path, n: int, poses: int) -> int:
    """N sessions under `root` with the journal of one simulated session; its size, bytes."""
    template = root.parent / "template"
    record_simulated_session(template, SimulationOptions(array="scatter48", poses=poses,
                                                         mls_order=9, seed=1))
    first, rest = (template / "journal.jsonl").read_bytes().split(b"\n", 1)
    start = json.loads(first)
    for i in range(n):
        name = f"2026-01-01T00-00-00Z_{i:08d}"
        (root / name).mkdir(parents=True)
        start["session_id"] = name
        (root / name / "journal.jsonl").write_bytes(json.dumps(start).encode() + b"\n" + rest)
    return len(first) + 1 + len(rest)


class Daemon:
    """`micam daemon` on `root`, started and stopped; `request` sends raw frames."""

    def __init__(self, tmp: Path, root: Path) -> None:
        config = tmp / "daemon.toml"
        config.write_text(f'session_root = "{root}"\n[sockets]\ncontrol = "ipc://{tmp}/c"\n'
                          f'events = "ipc://{tmp}/e"\n[simulation]\narray = "scatter48"\n'
                          "mls_order = 9\n")
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        notify_path = tmp / f"notify-{time.monotonic_ns()}"
        self.notify.bind(str(notify_path))
        self.notify.settimeout(120)
        log = (Path(tempfile.gettempdir()) / "micam-bench-sessions-list.log").open("w")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "micam.cli", "daemon", "--config", str(config)],
            env={**os.environ, "NOTIFY_SOCKET": str(notify_path)}, cwd=REPO, stdout=log,
            stderr=log)
        while b"READY=1" not in self.notify.recv(4096):
            pass
        self.started = time.perf_counter()
        self.context = zmq.Context()
        self.endpoint = f"ipc://{tmp}/c"

    def request(self, command: str) -> tuple[float, bytes]:
        """(round trip in seconds, raw reply) of one request."""
        sock = self.context.socket(zmq.REQ)
        sock.linger = 0
        sock.connect(self.endpoint)
        try:
            t0 = time.perf_counter()
            sock.send(json.dumps({"v": 2, "command": command}).encode())
            if not sock.poll(60_000):
                raise RuntimeError(f"no reply to {command}")
            raw = sock.recv()
            return time.perf_counter() - t0, raw
        finally:
            sock.close()

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(60)
        self.notify.close()
        self.context.destroy(linger=0)


def indexed(raw: bytes) -> bool:
    return bool(json.loads(raw)["result"]["complete"])


def wait_indexed(daemon: Daemon) -> tuple[float, list[float]]:
    """Seconds from READY until the index is complete, and the ping round trips meanwhile."""
    pings = []
    while True:
        pings.append(daemon.request("ping")[0])
        if indexed(daemon.request("sessions.list")[1]):
            return time.perf_counter() - daemon.started, pings
        time.sleep(0.05)


def ms(seconds: float) -> float:
    return round(seconds * 1000, 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=10_000)
    parser.add_argument("--poses", type=int, default=5, help="poses of each stored session")
    parser.add_argument("--requests", type=int, default=30)
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "sessions_list.json")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        root = tmp / "sessions"
        journal_bytes = fill_root(root, args.sessions, args.poses)
        daemon = Daemon(tmp, root)
        try:
            index_s, pings = wait_indexed(daemon)
            times, parse = [], []
            for _ in range(args.requests):
                elapsed, raw = daemon.request("sessions.list")
                times.append(elapsed)
                t0 = time.perf_counter()
                reply = Reply.model_validate_json(raw)
                parse.append(time.perf_counter() - t0)
            listed = len(reply.result["sessions"])
        finally:
            daemon.stop()
        daemon = Daemon(tmp, root)
        try:
            restart_s, _ = wait_indexed(daemon)
        finally:
            daemon.stop()

    times.sort()
    figures = {
        "sessions": args.sessions,
        "listed": listed,
        "journal_bytes_each": journal_bytes,
        "first_index_s": round(index_s, 2),
        "ping_during_first_index_median_ms": ms(statistics.median(pings)),
        "ping_during_first_index_max_ms": ms(max(pings)),
        "list_round_trip_median_ms": ms(statistics.median(times)),
        "list_round_trip_p90_ms": ms(times[int(0.9 * (len(times) - 1))]),
        "list_round_trip_max_ms": ms(times[-1]),
        "list_reply_bytes": len(raw),
        "client_parse_median_ms": ms(statistics.median(parse)),
        "restart_index_s": round(restart_s, 2),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
    }
    report(figures, args.out, 36)


if __name__ == "__main__":
    main()
