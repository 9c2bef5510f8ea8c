"""Shared test helpers: a daemon in a subprocess, and bounded drive loops (the thread daemon
and the small world are micam.testing's, public for users' tests too).

Readiness is a handshake, never a sleep: a subprocess daemon reports READY=1 on a notify socket
exactly as it does to systemd; a thread daemon has bound its sockets before its thread starts.
Every wait is bounded in time (and every loop in count).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import zmq

from acquisition.daemon.client import DaemonClient
from acquisition.contracts.protocol import StatusResult
from micam.testing import SMALL_WORLD, ThreadDaemon
from micam.testing import small_daemon_config as small_config

__all__ = ["SMALL_WORLD", "ThreadDaemon", "small_config"]  # re-exported for the tests

WAIT_S = 60.0
POLL_S = 0.01  # status polling period of the drive loops (each poll is a bounded request)
REPO = Path(__file__).resolve().parents[3]


def write_toml(path: Path, root: Path, extra: str = "") -> Path:
    """The TOML twin of `small_config`, for daemons started from the command line."""
    world = "\n".join(f"{k} = {v!r}".replace("'", '"') for k, v in SMALL_WORLD.items())
    path.write_text(
        f'session_root = "{root}/sessions"\npoll_interval_s = 0.02\n{extra}\n'
        f'[sockets]\ncontrol = "ipc://{root}/control"\nevents = "ipc://{root}/events"\n'
        f"[simulation]\n{world}\n")
    return path


@dataclass
class DaemonProcess:
    """`micam daemon --config FILE` in a subprocess, with a notify socket for its messages."""

    config: Path
    root: Path
    env: dict[str, str] = field(default_factory=dict)
    script: list[str] | None = None  # another entry point (the crash harness)
    pass_fds: tuple[int, ...] = ()  # descriptors the daemon inherits (a config pipe, /dev/fd/N)

    def __post_init__(self) -> None:
        self.notify_path = self.root / f"notify-{time.monotonic_ns()}"
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.notify.bind(str(self.notify_path))
        env = {**os.environ, "NOTIFY_SOCKET": str(self.notify_path), **self.env}
        env.pop("JOURNAL_STREAM", None)
        command = self.script or [sys.executable, "-m", "micam.cli", "daemon", "--config"]
        self.log_path = self.notify_path.with_suffix(".log")  # a file: a pipe could fill up
        with self.log_path.open("w") as log:
            self.proc = subprocess.Popen([*command, str(self.config)], env=env, cwd=REPO,
                                         stdout=log, stderr=subprocess.STDOUT,
                                         pass_fds=self.pass_fds)

    def wait_message(self, prefix: str, timeout_s: float = WAIT_S) -> str:
        """The next notify message containing a line starting with `prefix` (others skipped)."""
        deadline = time.monotonic() + timeout_s
        for _ in range(10_000):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            self.notify.settimeout(min(remaining, 0.5))
            try:
                message = self.notify.recv(4096).decode()
            except TimeoutError:
                if self.proc.poll() is not None:
                    raise AssertionError(f"the daemon exited ({self.proc.returncode}) before "
                                         f"{prefix}: {self.log_path.read_text()}") from None
                continue
            if any(line.startswith(prefix) for line in message.splitlines()):
                return message
        raise AssertionError(f"no {prefix} from the daemon within {timeout_s} s")

    def client(self, timeout_s: float = 10.0) -> DaemonClient:
        return DaemonClient(f"ipc://{self.root}/control", timeout_s=timeout_s)

    def kill(self) -> None:
        self.proc.kill()
        self.proc.wait(WAIT_S)
        self.close()

    def wait_exit(self) -> int:
        code = self.proc.wait(WAIT_S)
        self.close()
        return code

    def close(self) -> None:
        self.notify.close()
        self.notify_path.unlink(missing_ok=True)


def rss_bytes(pid: int) -> int:
    """The resident memory of process `pid` (/proc/PID/status VmRSS), bytes."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no VmRSS for process {pid}")


def capture(client: DaemonClient) -> StatusResult:
    """Capture the current step and wait until it completed or was abandoned."""
    number = client.request("capture")["number"]
    return client.wait_until(
        lambda s: s.session is None or (s.last_capture is not None
                                        and s.last_capture.number >= number),
        WAIT_S, interval_s=POLL_S)


def capture_all(client: DaemonClient, limit: int = 50) -> StatusResult:
    """Capture step after step until the session closes (at most `limit` captures)."""
    for _ in range(limit):
        status = capture(client)
        if status.session is None:
            return status
    raise AssertionError(f"the session did not close after {limit} captures")


def wait_state(client: DaemonClient, *states: str) -> StatusResult:
    return client.wait_until(lambda s: s.state in states, WAIT_S, interval_s=POLL_S)


class FakeWorker:
    """A raw DEALER on a daemon's jobs (or files) socket: the test speaks for a worker, or for
    a rogue process pretending to be one."""

    def __init__(self, endpoint: str) -> None:
        self.context = zmq.Context()
        self.sock = self.context.socket(zmq.DEALER)
        self.sock.linger = 0
        self.sock.connect(endpoint)

    def send(self, message: dict | bytes, *extra: bytes) -> None:
        frame = message if isinstance(message, bytes) else json.dumps(message).encode()
        self.sock.send_multipart([frame, *extra])

    def receive(self, kind: str, timeout_s: float = WAIT_S) -> tuple[dict, list[bytes]]:
        """The next message of type `kind` (heartbeats skipped), with all its frames."""
        deadline = time.monotonic() + timeout_s
        for _ in range(100_000):
            left = deadline - time.monotonic()
            if left <= 0 or not self.sock.poll(round(left * 1000)):
                break
            frames = self.sock.recv_multipart()
            message = json.loads(frames[0])
            if message.get("type") == kind:
                return message, frames
        raise AssertionError(f"no {kind!r} message within {timeout_s} s")

    def close(self) -> None:
        self.context.destroy(linger=0)


def next_event(events, kind: str, **fields):
    """The next event of type `kind` with these field values (bounded in count and time)."""
    for _ in range(100_000):
        event = events.next(WAIT_S)
        assert event is not None, f"no {kind} event"
        if event.type == kind and all(getattr(event, k) == v for k, v in fields.items()):
            return event
    raise AssertionError(f"no {kind} event among the first 100000")
