"""Fakes and small worlds for testing code that uses micam, as micam's own tests do.

Nothing here needs hardware: the daemon runs on the simulated world, in a thread of the test
process; sessions are recorded by the real sequencer on simulated boards and cameras
(`sim.boards.SimulatedBoard`, `sim.cameras.SimulatedCamera`, which plug in where real ones do).

- `SMALL_WORLD`, `small_options`: a capture that takes a fraction of a second.
- `record_small_session(path)`: a complete simulated session on disk, with its truth.json.
- `small_daemon_config(root)`, `ThreadDaemon`: a daemon on the small world, with ipc sockets
  under `root`; `with ThreadDaemon(small_daemon_config(tmp)) as daemon: daemon.client()...`.
- `FakeDaemonClient`: what the `micam` commands use of `DaemonClient`, answering from a status
  and a list of events, for testing a script or a command without a daemon.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from acquisition.contracts.protocol import Event, StatusResult
from acquisition.daemon.client import DaemonClient
from acquisition.daemon.config import SocketsConfig
from acquisition.daemon.hardware import Hardware
from acquisition.daemon.service import Daemon
from sim.capture import SimulationOptions

from .hardware import open_hardware
from .simulated import record_simulated_session
from .simulated_hardware import MicamDaemonConfig, SimulationConfig

SMALL_WORLD: dict[str, Any] = {"array": "scatter48", "poses": 3, "mls_order": 9, "seed": 3}
"""48 scattered microphones, one camera, 3 poses, short bursts: enough to calibrate."""

STOP_WAIT_S = 60.0


def small_options(**overrides: Any) -> SimulationOptions:
    """The small world's simulation options (`overrides` replace any of them)."""
    return SimulationOptions(**{**SMALL_WORLD, **overrides})


def record_small_session(path: Path, **overrides: Any) -> Path:
    """Record a complete simulated session of the small world at `path` (a new directory),
    its ground truth in path/truth.json; returns `path`."""
    record_simulated_session(path, small_options(**overrides))
    return path


def small_daemon_config(root: Path, **overrides: Any) -> MicamDaemonConfig:
    """A daemon configuration on the small simulated world, with ipc sockets and sessions under
    `root` (`overrides`: any other top-level field)."""
    fields = {
        "session_root": root / "sessions",
        "sockets": SocketsConfig(control=f"ipc://{root}/control", events=f"ipc://{root}/events"),
        "simulation": SimulationConfig(**SMALL_WORLD),
        "poll_interval_s": 0.02,
        **overrides,
    }
    return MicamDaemonConfig(**fields)


class ThreadDaemon:
    """A daemon serving in a background thread of this process (fast; no signals). Its sockets
    are bound when the constructor returns: no wait is needed before the first request."""

    def __init__(self, config: MicamDaemonConfig, hardware: Hardware | None = None) -> None:
        self.config = config
        self.hardware = hardware or open_hardware(config)
        self.daemon = Daemon(config, self.hardware)
        self.thread = threading.Thread(target=self.daemon.serve_forever, daemon=True)
        self.thread.start()

    def client(self, timeout_s: float = 10.0) -> DaemonClient:
        return DaemonClient(self.config.sockets.control, timeout_s=timeout_s)

    def stop(self) -> None:
        self.daemon.terminate()
        self.thread.join(STOP_WAIT_S)
        if self.thread.is_alive():
            raise RuntimeError(f"the daemon did not stop within {STOP_WAIT_S} s")

    def __enter__(self) -> ThreadDaemon:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()


class _FakeStream:
    def __init__(self, events: Iterable[Event]) -> None:
        self._events = list(events)

    def next(self, timeout_s: float) -> Event | None:
        return self._events.pop(0) if self._events else None

    def close(self) -> None:
        self._events.clear()


class FakeDaemonClient:
    """A stand-in for `DaemonClient`: `status()` returns `status`, `subscribe()` streams
    `events` once each, `request(command, **args)` answers from `replies` (a dict or a
    callable of the arguments) and records every request in `requests`."""

    def __init__(self, status: StatusResult, events: Iterable[Event] = (),
                 replies: dict[str, dict[str, Any] | Callable[..., dict[str, Any]]]
                 | None = None) -> None:
        self._status, self._events = status, list(events)
        self.replies = replies or {}
        self.requests: list[tuple[str, dict[str, Any]]] = []

    def __enter__(self) -> FakeDaemonClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        pass

    def close(self) -> None:
        pass

    def status(self) -> StatusResult:
        return self._status

    def subscribe(self, previews: bool = False) -> _FakeStream:
        return _FakeStream(self._events)

    def request(self, command: str, **args: Any) -> dict[str, Any]:
        self.requests.append((command, args))
        if command not in self.replies:
            raise KeyError(f"FakeDaemonClient has no reply for {command!r}; pass it in replies")
        reply = self.replies[command]
        return reply(**args) if callable(reply) else reply

    def wait_until(self, done: Callable[[StatusResult], bool], timeout_s: float,
                   on_event: Callable[[Event], None] | None = None,
                   stream: _FakeStream | None = None) -> StatusResult:
        """Hands every queued event to `on_event`, then returns the status (which must be
        `done`: a fake has nothing to wait for)."""
        if stream is not None and on_event is not None:
            while (event := stream.next(0)) is not None:
                on_event(event)
        if not done(self._status):
            raise TimeoutError("FakeDaemonClient's status is not what the caller waits for")
        return self._status
