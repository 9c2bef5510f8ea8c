"""Worker processes for the end-to-end tests, and a bounded wait on the daemon's status."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from acquisition.daemon.client import DaemonClient, EventStream
from acquisition.contracts.protocol import Event, StatusResult
from tests.acquisition.daemon.helpers import REPO, WAIT_S, write_toml

HARNESS = Path(__file__).with_name("worker_harness.py")
WORKERS_TOML = ("[workers]\nheartbeat_interval_s = 0.1\nliveness = 5\nlive_min_poses = 3\n")


def daemon_toml(root: Path) -> Path:
    """The small simulated world of the daemon tests, with fast heartbeats."""
    return write_toml(root / "daemon.toml", root, WORKERS_TOML)


@dataclass
class Holds:
    """The datagram socket harness workers report their hold point on, and the token."""

    root: Path
    path: Path = field(init=False)

    def __post_init__(self) -> None:
        self.path = self.root / "holds"
        self.token = self.root / "hold-token"
        self.token.touch()
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(self.path))

    def wait(self, timeout_s: float = WAIT_S) -> str:
        """The name of the worker that holds a final job."""
        self.sock.settimeout(timeout_s)
        message = self.sock.recv(256).decode()
        assert message.startswith("HOLDING="), message
        return message.removeprefix("HOLDING=")

    def close(self) -> None:
        self.sock.close()


def start_worker(root: Path, name: str, holds: Holds) -> subprocess.Popen:
    """A harness worker process connected to the daemon of `root`."""
    env = {**os.environ, "HOLD_TOKEN": str(holds.token), "NOTIFY_SOCKET": str(holds.path)}
    log = (root / f"{name}.log").open("w")
    return subprocess.Popen(
        [sys.executable, str(HARNESS), "--connect", f"ipc://{root}/control", "--name", name,
         "--cache", str(root / f"cache-{name}"), "--heartbeat", "0.1", "--no-joint"],
        env=env, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)


def stop_worker(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(WAIT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(WAIT_S)


def wait_calibration(client: DaemonClient, stream: EventStream, events: list[Event]
                     ) -> StatusResult:
    """Wait until a final job is done or failed, collecting the events meanwhile and those
    published before it (status is answered after them, so they are on their way)."""
    status = client.wait_until(lambda s: s.calibration.done + s.calibration.failed >= 1, WAIT_S,
                               on_event=events.append, stream=stream, interval_s=0.05)
    for _ in range(10_000):
        event = stream.next(0.5)
        if event is None:
            break
        events.append(event)
    return status


def wait_workers(client: DaemonClient, n: int) -> StatusResult:
    """Readiness handshake: the daemon lists `n` connected workers."""
    return client.wait_until(lambda s: len(s.calibration.workers) >= n, WAIT_S, interval_s=0.05)
