"""Runs the daemon with a crash point, for the SIGKILL and SIGTERM tests (test code only).

    python crash_harness.py POINT N CONFIG

At the N-th occurrence of POINT the daemon reports CRASHPOINT=POINT on its notify socket and
stops dead there, until a SIGTERM (which the daemon handles) releases it, or a SIGKILL ends it:

- burst: inside the N-th burst, after the first board delivered its samples;
- between_files: right after the N-th recording was written and journaled;
- manifest: while writing the N-th manifest, its new content in manifest.json.partial.
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import acquisition.contracts.session._writer as session_writer
from micam.daemon import run_daemon
from acquisition.daemon.service import Daemon
from acquisition.daemon.systemd import sd_notify
from acquisition.contracts.session import partial_path
from daq import SyncGroup
from sim.boards import SimulatedBoard

released = threading.Event()
counts = {"bursts": 0, "recordings": 0, "manifests": 0}


def hang(point: str) -> None:
    sd_notify(f"CRASHPOINT={point}")
    for _ in range(60_000):  # at most ten minutes; the test kills or releases it long before
        if released.wait(0.01):
            return


def arm(point: str, nth: int) -> None:
    terminate = Daemon.terminate

    def terminate_and_release(self: Daemon) -> None:
        terminate(self)
        released.set()

    Daemon.terminate = terminate_and_release  # type: ignore[method-assign]

    if point == "burst":
        acquire, read = SyncGroup.acquire, SimulatedBoard.read

        def counting_acquire(self, *args, **kwargs):
            counts["bursts"] += 1
            return acquire(self, *args, **kwargs)

        def read_then_hang(self, *args, **kwargs):
            block = read(self, *args, **kwargs)
            if counts["bursts"] == nth and not released.is_set():
                hang(point)
            return block

        SyncGroup.acquire = counting_acquire  # type: ignore[method-assign]
        SimulatedBoard.read = read_then_hang  # type: ignore[method-assign]
    elif point == "between_files":
        write_recording = session_writer.SessionWriter.write_recording

        def write_then_hang(self, *args, **kwargs):
            path = write_recording(self, *args, **kwargs)
            counts["recordings"] += 1
            if counts["recordings"] == nth:
                hang(point)
            return path

        session_writer.SessionWriter.write_recording = write_then_hang  # type: ignore[method-assign]
    elif point == "manifest":
        write_atomic = session_writer.write_atomic

        def hang_inside_manifest(path: Path, fill, *, replace: bool = False):
            if path.name == session_writer.MANIFEST_NAME:
                counts["manifests"] += 1
                if counts["manifests"] == nth:
                    with partial_path(path).open("wb") as fh:
                        fill(fh)
                    hang(point)
            return write_atomic(path, fill, replace=replace)

        session_writer.write_atomic = hang_inside_manifest
    else:
        raise SystemExit(f"unknown crash point {point!r}")


if __name__ == "__main__":
    arm(sys.argv[1], int(sys.argv[2]))
    sys.exit(run_daemon(Path(sys.argv[3])))
