"""A JACK server of micam's own: jackd on its dummy driver (the machine's clock, no sound card)
with 16 capture and 8 playback ports at 96 kS/s, under a private name so that it never meets
another server: the audio server the simulated world's JACK client (sim.jack_world) plays in,
for the audio backend's tests (tests/daq/audio) and its benchmark
(benchmarks/bench_live_audio.py).

It needs jackd (Debian: jackd2) and, for the backend, the PortAudio library (libportaudio2):
`APT` installs both; `.ci/run` does.
"""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
from pathlib import Path

RATE_HZ = 96_000
PERIOD = 2048
CAPTURE_PORTS = 16
PLAYBACK_PORTS = 8
APT = "apt-get install -y jackd2 libportaudio2"
START_S = 20.0


class JackUnavailableError(RuntimeError):
    """jackd, PortAudio or JACK-Client is missing, or jackd did not start; says what to do."""


def missing_audio_stack() -> str | None:
    """What is missing for the simulated audio world (with the command that installs it), or
    None: jackd, the PortAudio library, JACK-Client."""
    if shutil.which("jackd") is None:
        return f"the simulated audio world needs a JACK server: {APT} (as root)"
    try:
        import sounddevice  # noqa: F401
    except OSError as exc:
        return f"the audio backend needs the PortAudio library ({exc}): {APT}"
    try:
        import jack  # noqa: F401
    except (ImportError, OSError) as exc:
        return (f"the simulated world's JACK client needs JACK-Client ({exc}): "
                f"pip install JACK-Client (and {APT})")
    return None


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

    def __init__(self, name: str, log_dir: Path, period: int = PERIOD) -> None:
        self.name = name
        self.period = period
        self.env = {**os.environ, "JACK_NO_AUDIO_RESERVATION": "1",
                    "JACK_DEFAULT_SERVER": name, "JACK_NO_START_SERVER": "1"}
        self.log = log_dir / f"jackd-{name}.log"
        mode = "-R" if realtime_permitted() else "--no-realtime"
        with self.log.open("w") as log:
            self.proc = subprocess.Popen(
                ["jackd", "-n", name, mode, "-d", "dummy", "-r", str(RATE_HZ),
                 "-p", str(period), "-C", str(CAPTURE_PORTS), "-P", str(PLAYBACK_PORTS)],
                env=self.env, stdout=log, stderr=subprocess.STDOUT)
        ready = subprocess.run(["jack_wait", "-s", name, "-w", "-t", str(int(START_S))],
                               env=self.env, capture_output=True, text=True, timeout=START_S + 5)
        if ready.returncode != 0 or self.proc.poll() is not None:
            self.kill()
            raise JackUnavailableError(f"jackd did not start: {self.log.read_text()[-2000:]}")

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
