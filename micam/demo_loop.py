"""The whole loop on one machine with no hardware: the daemon on the simulated world, a
calibration worker, a capture scripted through the `micam` commands, the live and the final
calibration, and a short report against the simulated truth.

    python -m micam.demo_loop --out out/loop [--poses 20]

Both processes start with readiness handshakes (the daemon's READY=1 on a notify socket, the
worker's appearance in the daemon's status), every wait is bounded, and both are stopped
(SIGTERM, then SIGKILL if they linger) whatever happens. `benchmarks/bench_worker.py` uses the
same `Loop`.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import TracebackType

from .cli import main as micam
from acquisition.daemon.client import DaemonClient, EventStream
from micam.display import format_live
from acquisition.contracts.protocol import CalibrationEvent, LiveCalibrationEvent

STOP_WAIT_S = 30.0


class Loop:
    """A daemon and a worker in subprocesses, under `root` (ipc sockets, sessions, logs)."""

    def __init__(self, root: Path, poses: int, array: str = "sphere72", mls_order: int = 12,
                 seed: int = 1, live_min_poses: int = 4) -> None:
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)
        sockets = self.root / "run"  # private: the daemon refuses sockets others may reach
        sockets.mkdir(exist_ok=True)
        sockets.chmod(0o700)
        self.control = f"ipc://{sockets}/control"
        self.config = self.root / "daemon.toml"
        self.config.write_text(
            f'session_root = "{self.root}/sessions"\n'
            f"[sockets]\ncontrol = \"{self.control}\"\nevents = \"ipc://{sockets}/events\"\n"
            f"[simulation]\narray = \"{array}\"\nposes = {poses}\nmls_order = {mls_order}\n"
            f"seed = {seed}\n[workers]\nlive_min_poses = {live_min_poses}\n")
        self._procs: list[subprocess.Popen] = []

    def __enter__(self) -> Loop:
        try:
            self._start_daemon()
            self._start("worker", "worker", "--control", self.control, "--name", "demo-worker",
                        "--cache", str(self.root / "worker-cache"))
            with self.client() as client:
                client.wait_until(lambda s: len(s.calibration.workers) >= 1, 60.0,
                                  interval_s=0.1)
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: type[BaseException] | BaseException | TracebackType | None) -> None:
        self.close()

    def client(self, timeout_s: float = 10.0) -> DaemonClient:
        return DaemonClient(self.control, timeout_s=timeout_s)

    @property
    def daemon_pid(self) -> int:
        """The daemon's process id (it is started first)."""
        return self._procs[0].pid

    def _start(self, name: str, *args: str) -> subprocess.Popen:
        log = (self.root / f"{name}.log").open("w")
        proc = subprocess.Popen([sys.executable, "-m", "micam.cli", *args],
                                stdout=log, stderr=subprocess.STDOUT,
                                env={**os.environ, "NOTIFY_SOCKET": str(self.root / "notify")})
        self._procs.append(proc)
        return proc

    def _start_daemon(self) -> None:
        """Start the daemon and wait for its READY=1 (the systemd notify handshake)."""
        path = self.root / "notify"
        path.unlink(missing_ok=True)
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as notify:
            notify.bind(str(path))
            proc = self._start("daemon", "daemon", "--config", str(self.config))
            notify.settimeout(1.0)
            for _ in range(60):
                try:
                    if b"READY=1" in notify.recv(4096):
                        return
                except TimeoutError:
                    if proc.poll() is not None:
                        break
            raise RuntimeError(f"the daemon did not start; see {self.root / 'daemon.log'}")

    def close(self) -> None:
        """Stop the processes this loop started: SIGTERM, then SIGKILL after STOP_WAIT_S."""
        for proc in reversed(self._procs):
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in reversed(self._procs):
            try:
                proc.wait(STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(STOP_WAIT_S)
        self._procs.clear()


def scripted_capture(loop: Loop, poses: int, show: bool = True) -> tuple[Path, float]:
    """Start a session and capture every step through the `micam` commands; the session's
    path and the monotonic time its last pose was captured."""
    control = ["--control", loop.control]
    with loop.client() as client:
        if micam(["session", "start", "--poses", str(poses), *control]) != 0:
            raise RuntimeError("micam session start failed")
        session = client.status().session
        if session is None:
            raise RuntimeError("micam session start returned but the daemon has no session")
        path, total = Path(session.path), session.steps_total
    out = None if show else open(os.devnull, "w")
    try:
        for _ in range(total * 3):  # quality retries may add captures
            with loop.client() as client:
                if client.status().session is None:
                    return path, time.monotonic()
            saved = sys.stdout
            sys.stdout = out or saved
            try:
                code = micam(["capture", *control])
            finally:
                sys.stdout = saved
            if code != 0:
                raise RuntimeError("micam capture failed")
    finally:
        if out is not None:
            out.close()
    raise RuntimeError(f"the session did not close after {total * 3} captures")


def wait_final(stream: EventStream, timeout_s: float) -> CalibrationEvent:
    """The `calibration` event of the session's final result (bounded by `timeout_s`); the
    live calibrations that arrive meanwhile are printed."""
    deadline = time.monotonic() + timeout_s
    for _ in range(1_000_000):
        left = deadline - time.monotonic()
        if left <= 0:
            break
        event = stream.next(min(left, 1.0))
        if isinstance(event, LiveCalibrationEvent):
            print(format_live(event.update), flush=True)
        if isinstance(event, CalibrationEvent):
            return event
    raise RuntimeError(f"no final calibration within {timeout_s:g} s")


def report(session: Path, result_path: Path, out: Path) -> list[str]:
    """A short report against the simulated truth: lines printed, report.md and geometry.png
    (the array in three views with its errors against the truth magnified, as in the
    calibration report)."""
    from calibration.figures.geometry import geometry_figure
    from calibration.figures.style import save
    from calibration.report import array_picture, significant
    from calibration.result import CalibrationResult, compare_with_truth

    result = CalibrationResult.model_validate_json(result_path.read_text())
    truth = json.loads((session / "truth.json").read_text())
    errors = compare_with_truth(result, truth)
    lines = [
        f"session         {session}",
        f"result          {result_path}",
        f"microphones     {len(result.microphones)}",
        f"mean error      {significant(errors['mean_mic_error_m'] * 1e3)} mm against the "
        f"simulated truth (max {significant(errors['max_mic_error_m'] * 1e3)} mm)",
        f"speed of sound  {result.speed_of_sound_m_s:.3f} m/s (truth "
        f"{truth['speed_of_sound_m_s']:.3f}, error "
        f"{significant(errors['speed_of_sound_error_m_s'], signed=True)})",
        f"focal length    largest relative error {errors['max_focal_error_rel']:.2e}",
    ]
    save(geometry_figure(array_picture(result, truth)), out / "geometry.png")
    (out / "report.md").write_text(
        "# micam: the whole loop\n\n```\n" + "\n".join(lines) + "\n```\n\n"
        "The array in three views: each arrow is a microphone's error against the simulated "
        "truth, magnified by the factor in the legend; the ellipses are the calibration's 95 % "
        "uncertainty at the same scale.\n\n![geometry](geometry.png)\n")
    return [*lines, f"pictures        {out / 'geometry.png'}, report {out / 'report.md'}"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, required=True, help="working directory (new)")
    parser.add_argument("--poses", type=int, default=20)
    parser.add_argument("--mls-order", type=int, default=12)
    parser.add_argument("--timeout", type=float, default=1800.0,
                        help="longest wait for the final result, seconds")
    args = parser.parse_args(argv)
    with Loop(args.out, args.poses, mls_order=args.mls_order) as loop, loop.client() as client:
        print(f"to watch it in a browser, run in another terminal: {sys.executable} -m "
              f"micam.cli web --control {loop.control}   (then open "
              "http://127.0.0.1:8765/; docs/operator.md)", flush=True)
        stream = client.subscribe()
        try:
            session, _ = scripted_capture(loop, args.poses)
            print("session closed; waiting for the worker's final calibration", flush=True)
            final = wait_final(stream, args.timeout)
        finally:
            stream.close()
    print("\n".join(report(session, Path(final.path), args.out)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
