"""Chaos: the daemon and the calibration worker killed (SIGKILL and SIGTERM) at random points
of a simulated capture and its calibration, restarted each time, until the session is complete
and calibrated.

It must end with every recording intact and bit-identical to an uninterrupted capture of the
same seed, every step recorded once, the final job done once (one result.json, the one the
outbox records), and a calibration equal to the uninterrupted capture's (`SAME_RELATIVE`).
The daemon resumes by itself (`resume_at_start = "auto"`); the test plays the operator (a
`capture` whenever the daemon waits for one).

Default: 4 rounds (each of the four kills once, in random order, about a minute). The long
run, 20 rounds: `MICAM_LONG_TESTS=1` (or MICAM_CHAOS_ROUNDS=N); MICAM_CHAOS_SEED replays a run.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import random
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from acquisition.daemon.client import DaemonClient, DaemonError
from acquisition.daemon.outbox import JobRecord
from acquisition.contracts.session import SessionReader, journal_records
from micam.simulated import record_simulated_session
from calibration.pipeline import CalibrationOptions, calibrate
from sim.capture import SimulationOptions

from .helpers import REPO, SMALL_WORLD, DaemonProcess, rss_bytes, write_toml

LONG = os.environ.get("MICAM_LONG_TESTS") == "1"
ROUNDS = int(os.environ.get("MICAM_CHAOS_ROUNDS", "20" if LONG else "4"))
SEED = int(os.environ.get("MICAM_CHAOS_SEED", str(time.time_ns() % 10**6)))
DEADLINE_S = 120.0 + 45.0 * ROUNDS
WAITING = {"references", "reference_microphone", "waiting_for_pose"}
KILLS = list(itertools.product(("daemon", "worker"), (signal.SIGKILL, signal.SIGTERM)))
WORKERS = ("[workers]\nheartbeat_interval_s = 0.1\nliveness = 5\nlive_min_poses = 3\n"
           "max_attempts = 20\n")  # every killed lease is an attempt
VOLATILE = ("session_id", "timings_s")  # what two calibrations of one capture may differ in
MAX_RSS = {"daemon": 400 * 2**20, "worker": 400 * 2**20}
"""Resident memory ceilings through every round (measured: 277 MiB and 165 MiB at most)."""


def _result(document: dict) -> dict:
    return {k: v for k, v in document.items() if k not in VOLATILE}


SAME_RELATIVE = 1e-9
"""How closely the worker's numbers must equal the uninterrupted calibration's. They were
compared bit for bit; under pytest-xdist two runs of 5 here differed in the last digits of the
uncertainties (latency std 8.383846294679323e-08 against ...665e-08, 4e-14 relative), the
positions equal, for a reason not found yet (this process and the worker's differ; neither
chaos seed reproduced it replayed alone). Anything a lost or repeated step or pose would
change moves them by far more."""


def _same(found: object, expected: object) -> bool:
    """`found` equals `expected`, numbers within `SAME_RELATIVE` of each other."""
    if isinstance(found, dict) and isinstance(expected, dict):
        return found.keys() == expected.keys() and all(_same(found[k], expected[k])
                                                        for k in found)
    if isinstance(found, list) and isinstance(expected, list):
        return len(found) == len(expected) and all(map(_same, found, expected))
    if isinstance(found, float) and isinstance(expected, float):
        return math.isclose(found, expected, rel_tol=SAME_RELATIVE, abs_tol=0.0)
    return found == expected


def _recordings(session: Path) -> dict[str, dict[str, str]]:
    """The checksums of every recording and image of every completed step."""
    return {step: {name: f.sha256 for name, f in record.files.items() if f.role != "other"}
            for step, record in SessionReader(session).steps().items()}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The same capture without interruptions, calibrated as the worker does (no joint fit)."""
    path = tmp_path_factory.mktemp("uninterrupted") / "s"
    record_simulated_session(path, SimulationOptions(**SMALL_WORLD))
    run = calibrate(path, CalibrationOptions(joint=False))
    return path, json.loads(run.result.model_dump_json())


@dataclass
class Rig:
    """The daemon and the worker processes of one chaos run, restarted when they die."""

    root: Path
    daemon: DaemonProcess | None = None
    worker: subprocess.Popen | None = None
    log: list[str] = field(default_factory=list)
    peak_rss: dict[str, int] = field(default_factory=lambda: {"daemon": 0, "worker": 0})

    @property
    def config(self) -> Path:
        return self.root / "daemon.toml"

    def ensure_running(self) -> None:
        if self.daemon is None or self.daemon.proc.poll() is not None:
            if self.daemon is not None:
                self.daemon.close()
            self.daemon = DaemonProcess(self.config, self.root)
            self.daemon.wait_message("READY=1")
        if self.worker is None or self.worker.poll() is not None:
            log = (self.root / "worker.log").open("a")
            self.worker = subprocess.Popen(
                [sys.executable, "-m", "micam.cli", "worker", "--control",
                 f"ipc://{self.root}/control", "--name", "chaos", "--cache",
                 str(self.root / "cache"), "--heartbeat", "0.1", "--daemon-timeout", "2",
                 "--no-joint"], cwd=REPO, stdout=log, stderr=subprocess.STDOUT)

    def kill(self, target: str, signum: signal.Signals, what: str) -> None:
        proc = self.daemon.proc if target == "daemon" and self.daemon else self.worker
        assert proc is not None
        self.log.append(f"{signum.name} {target} in {what}")
        proc.send_signal(signum)
        proc.wait(60)

    def client(self) -> DaemonClient:
        return DaemonClient(f"ipc://{self.root}/control", timeout_s=3.0)

    def measure(self) -> None:
        """Note the resident memory of the daemon and the worker (the largest seen each)."""
        for name, proc in (("daemon", self.daemon.proc if self.daemon else None),
                           ("worker", self.worker)):
            if proc is not None and proc.poll() is None:
                try:
                    rss = rss_bytes(proc.pid)
                except (OSError, AssertionError):  # it died just now
                    continue
                self.peak_rss[name] = max(self.peak_rss[name], rss)

    def stop(self) -> None:
        for proc in (self.daemon.proc if self.daemon else None, self.worker):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(60)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(60)
        if self.daemon is not None:
            self.daemon.close()


def _final_job(root: Path) -> JobRecord | None:
    found = list((root / "sessions.outbox").glob("*.final.json"))
    return JobRecord.model_validate_json(found[0].read_text()) if found else None


def _phase(session: Path | None, steps: int) -> int:
    """How far the capture is: its completed steps, or `steps` once it is complete (then the
    calibration runs)."""
    if session is None:
        return 0
    reader = SessionReader(session)
    return steps if reader.status == "complete" else len(reader.steps())


def _operate(client: DaemonClient, session: Path | None) -> tuple[Path, bool]:
    """One turn of the operator: start the session once, capture whenever the daemon waits.
    Returns the session and whether a step is being captured now."""
    status = client.status()
    if session is None:
        return Path(client.request("session.start", poses=SMALL_WORLD["poses"])
                    ["session"]["path"]), False
    if status.session is not None:
        finished = status.last_capture.number if status.last_capture else 0
        if status.state in WAITING and status.captures_requested == finished:
            client.request("capture")
    return session, status.state == "capturing"


@pytest.mark.slow
def test_kills_at_random_points_lose_nothing_and_change_nothing(
        tmp_path: Path, uninterrupted: tuple[Path, dict]) -> None:
    """Each round kills at a random point: in a random step (the capture of a step, a random
    fraction of a second in) or during the calibration, the daemon or the worker, with SIGKILL
    or SIGTERM."""
    write_toml(tmp_path / "daemon.toml", tmp_path, 'resume_at_start = "auto"\n' + WORKERS)
    rng = random.Random(SEED)
    steps = len(SessionReader(uninterrupted[0]).steps())
    kills = [k for _ in range(ROUNDS // len(KILLS) + 1) for k in rng.sample(KILLS, len(KILLS))]
    kills = kills[:ROUNDS]
    when = sorted(rng.randrange(steps + 1) for _ in range(ROUNDS))  # a step, or `steps`
    rig = Rig(tmp_path)
    session: Path | None = None
    deadline = time.monotonic() + DEADLINE_S
    try:
        while time.monotonic() < deadline:
            rig.ensure_running()
            try:
                with rig.client() as client:
                    session, capturing = _operate(client, session)
            except DaemonError:  # the daemon is starting, dying, or busy resuming
                continue
            phase = _phase(session, steps)
            if when and phase >= when[0] and (capturing or phase == steps):
                time.sleep(rng.uniform(0.0, 0.25))  # somewhere inside the step
                when.pop(0)
                job = _final_job(tmp_path)
                rig.kill(*kills.pop(0), f"step {phase + 1} of {steps}" if phase < steps
                         else f"the calibration (job {job.state if job else 'not queued'})")
                continue
            rig.measure()
            job = _final_job(tmp_path)
            if not kills and job is not None and job.state in ("done", "failed"):
                break
            time.sleep(0.02)
    finally:
        rig.stop()
    story = f"chaos seed {SEED}: " + "; ".join(rig.log)
    print(story, {k: f"{v / 2**20:.0f} MiB" for k, v in rig.peak_rss.items()})  # pytest -s
    assert not kills, f"{story}: did not finish within {DEADLINE_S:g} s"
    for name, peak in rig.peak_rss.items():
        assert 0 < peak <= MAX_RSS[name], f"{story}: the {name} reached {peak / 2**20:.0f} MiB"
    assert session is not None

    reference, expected = uninterrupted
    reader = SessionReader(session)
    assert reader.status == "complete" and reader.verify() == [], story
    assert _recordings(session) == _recordings(reference), story
    ends = [r.step for r in journal_records(session / "journal.jsonl") if r.kind == "step_end"]
    assert len(ends) == len(set(ends)) == len(reader.steps()), story

    job = _final_job(tmp_path)
    assert job is not None and job.state == "done", f"{story}: {job}"
    stored = session / "calibration" / "result.json"
    assert hashlib.sha256(stored.read_bytes()).hexdigest() == job.result_sha256, story
    assert sorted(p.name for p in stored.parent.iterdir() if p.suffix == ".json") in (
        ["result.json"], ["live.json", "result.json"]), story
    found = _result(json.loads(stored.read_text()))
    assert _same(found, _result(expected)), f"{story}: {found} != {_result(expected)}"
