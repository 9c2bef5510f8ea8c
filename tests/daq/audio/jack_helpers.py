"""A JACK server of the test suite's own: jackd on its dummy driver (the machine's clock, no
sound card), 16 capture and 8 playback ports at 96 kS/s, under a private name so that tests
never meet another server (docs/hardware.md, "Testing").

What the tests need and how to install it: jackd (Debian: jackd2), the PortAudio library
(libportaudio2) and the JACK-Client package (the world client, a test extra). A missing piece
fails the test with the command that installs it: `.ci/run` installs them, so CI runs these
tests on a fresh machine.
"""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import time
from pathlib import Path

import pytest

RATE_HZ = 96_000
PERIOD = 2048
CAPTURE_PORTS = 16
PLAYBACK_PORTS = 8
APT = "apt-get install -y jackd2 libportaudio2"
START_S = 20.0


def require_audio_stack() -> None:
    """Fail (with the install command) unless jackd, PortAudio and JACK-Client are there."""
    if shutil.which("jackd") is None:
        pytest.fail(f"the audio backend's tests need a JACK server: {APT} (as root)")
    try:
        import sounddevice  # noqa: F401
    except OSError as exc:
        pytest.fail(f"the audio backend's tests need the PortAudio library ({exc}): {APT}")
    try:
        import jack  # noqa: F401
    except (ImportError, OSError) as exc:
        pytest.fail(f"the audio backend's tests need JACK-Client ({exc}): "
                    "pip install -e '.[test]' (and {APT})")


def realtime_permitted() -> bool:
    """Whether this process may schedule threads realtime (root, or an rtprio limit)."""
    try:
        return os.geteuid() == 0 or resource.getrlimit(resource.RLIMIT_RTPRIO)[0] > 0
    except (AttributeError, OSError):
        return False


class JackServer:
    """`jackd -n NAME -d dummy ...` in a subprocess, ready when constructed: realtime where this
    machine permits it (its clients' process threads then preempt the machine's other work, as
    on a lab PC set up for audio), else --no-realtime (then a loaded machine makes xruns, which
    the tests capture again)."""

    def __init__(self, name: str, log_dir: Path) -> None:
        self.name = name
        self.env = {**os.environ, "JACK_NO_AUDIO_RESERVATION": "1",
                    "JACK_DEFAULT_SERVER": name, "JACK_NO_START_SERVER": "1"}
        self.log = log_dir / f"jackd-{name}.log"
        mode = "-R" if realtime_permitted() else "--no-realtime"
        with self.log.open("w") as log:
            self.proc = subprocess.Popen(
                ["jackd", "-n", name, mode, "-d", "dummy", "-r", str(RATE_HZ),
                 "-p", str(PERIOD), "-C", str(CAPTURE_PORTS), "-P", str(PLAYBACK_PORTS)],
                env=self.env, stdout=log, stderr=subprocess.STDOUT)
        ready = subprocess.run(["jack_wait", "-s", name, "-w", "-t", str(int(START_S))],
                               env=self.env, capture_output=True, text=True, timeout=START_S + 5)
        if ready.returncode != 0 or self.proc.poll() is not None:
            self.kill()
            pytest.fail(f"jackd did not start: {self.log.read_text()[-2000:]}")

    def kill(self) -> None:
        """Kill the server at once (SIGKILL: a server that vanishes) and wait for it."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(30)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.kill()


def wait_for(condition, timeout_s: float, what: str, poll_s: float = 0.02):  # noqa: ANN001
    """Poll `condition()` until it is truthy (bounded in time), returning its value."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll_s)
    raise AssertionError(f"{what} within {timeout_s} s")


XRUN_RETRIES = 3


def acquire_whole(group, outputs):  # noqa: ANN001, ANN201
    """`group.acquire(outputs)`, again after an xrun (a late period of this shared, loaded
    machine, which a daemon also captures again: tests/daq/audio/test_audio_board.py checks
    the xrun's own outcome), at most XRUN_RETRIES times."""
    from daq import OverrunError

    for attempt in range(XRUN_RETRIES):
        try:
            return group.acquire(outputs)
        except OverrunError:
            if attempt == XRUN_RETRIES - 1:
                raise
    raise AssertionError("unreachable")

