"""The simulated world as a JACK client: the room between an audio interface's ports.

`python -m sim.jack_world OPTIONS_JSON NAME` runs a JACK client called NAME with input ports
`spk_1` .. `spk_8` (what the interface plays to the rig's speakers) and output ports `mic_1`
.. `mic_16` (what its microphones hear: the array's microphones in order, then the reference
microphone, then silence). To PortAudio it is a device called NAME with 16 inputs and 8
outputs, which the audio backend opens like any interface; the server's clock is the device
clock. Its process callback runs `sim.audio_world.RoomFilter` on every period.

It is a process of its own (so that its callback never waits for another thread's Python),
driven over its standard input, one JSON object per line, each answered by a line `ok` (or
`error: ...`): `{"op": "perform", "instruction": {...}}` (the simulated operator sets the world
up as for the sequencer's instruction), `{"op": "live", "on": true}` (the live scene's sources
play, or stop), `{"op": "stall", "seconds": 0.05}` (the next callback sleeps that long: an xrun
for every client of the server). It ends when its standard input closes or the server goes
away. `WorldProcess` starts and drives it (sim.audio_capture).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from acquisition.contracts.errors import UserError
from acquisition.contracts.instructions import Instruction

from .audio_world import RANGE_V, RoomFilter
from .live_scene import demo_scene

SPEAKER_PORTS = 8
MIC_PORTS = 16
READY = "ready"
START_TIMEOUT_S = 60.0
REPLY_TIMEOUT_S = 30.0


class WorldStartError(UserError):
    """The world's JACK client did not start (no server, JACK-Client missing) or ended; says
    why and what to do."""


def _serve(options_json: str, name: str) -> None:
    """The client process's main loop (module docstring)."""
    import jack

    from .capture import SimulationOptions, world_for
    from .simulated_operator import SimulatedOperator, reference_stand_position
    from .poses import sample_poses

    options = SimulationOptions.model_validate_json(options_json)
    world, poses = world_for(options)
    operator = SimulatedOperator(world, poses, reference_stand_position(world.layout.cameras[0]))
    client = jack.Client(name, no_start_server=True)
    if client.samplerate != world.sample_rate_hz:
        raise SystemExit(f"the JACK server runs at {client.samplerate} S/s, the world at "
                         f"{world.sample_rate_hz:.0f}: start jackd with -r "
                         f"{world.sample_rate_hz:.0f}")
    n_receivers = world.layout.n_mics + 1
    if n_receivers > MIC_PORTS or world.rig.n_speakers > SPEAKER_PORTS:
        raise SystemExit(f"{n_receivers} receivers and {world.rig.n_speakers} speakers do not "
                         f"fit {MIC_PORTS} inputs and {SPEAKER_PORTS} outputs")
    speakers = [client.inports.register(f"spk_{k + 1}") for k in range(SPEAKER_PORTS)]
    mics = [client.outports.register(f"mic_{m + 1}") for m in range(MIC_PORTS)]
    room = RoomFilter(world, client.blocksize, seed=options.seed)
    stall = [0.0]
    gone = threading.Event()
    used = world.rig.n_speakers

    @client.set_process_callback
    def process(frames: int) -> None:
        if stall[0]:
            time.sleep(stall[0])
            stall[0] = 0.0
        drive = np.stack([p.get_array() for p in speakers[:used]], axis=1) * RANGE_V
        volts = room.process(drive.astype(np.float64)) / RANGE_V
        for m, port in enumerate(mics):
            port.get_array()[:] = volts[:, m] if m < n_receivers else 0.0

    @client.set_shutdown_callback
    def shutdown(status: jack.Status, reason: str) -> None:
        gone.set()

    def prefetch() -> None:  # the live scene rendered ahead of the callback
        try:  # as urgent as the callback (a realtime server's): it holds what the callback waits for
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        except (AttributeError, OSError):
            pass  # not permitted: the callback may then wait for it on a busy machine
        while not gone.wait(0.01):
            room.prefetch()

    threading.Thread(target=prefetch, name="micam-world-prefetch", daemon=True).start()
    with client:
        print(READY, flush=True)
        for line in sys.stdin:
            if gone.is_set():
                break
            try:
                command = json.loads(line)
                op = command["op"]
                if op == "perform":
                    operator.perform(Instruction.model_validate(command["instruction"]))
                    room.set_up()
                elif op == "live":
                    world.live_scene = demo_scene(world) if command["on"] else None
                    if world.live_scene is not None:
                        world.live_scene.mic_volts(0, 1)  # its first chunk, before it plays
                    room.play_scene(world.live_scene)
                elif op == "stall":
                    stall[0] = float(command["seconds"])
                else:
                    raise ValueError(f"unknown op {op!r}")
            except Exception as exc:  # a bad command: say so, keep serving
                print(f"error: {type(exc).__name__}: {exc}", flush=True)
                continue
            print("ok", flush=True)


class WorldProcess:
    """The world's JACK client in a child process (module docstring); close() ends it."""

    def __init__(self, options_json: str, name: str) -> None:
        self.name = name
        repo = Path(__file__).resolve().parents[1]
        self._log = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 - read on failure
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "sim.jack_world", options_json, name], cwd=repo,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log, text=True,
            env={**os.environ, "PYTHONPATH": str(repo)})
        self._lock = threading.Lock()
        line = self._line(START_TIMEOUT_S)
        if line != READY:
            self.close()
            raise WorldStartError(
                f"the simulated world's JACK client {name!r} did not start "
                f"({line or 'no answer'}; {self.stderr_tail() or 'nothing on stderr'}): is a "
                "JACK server running at 96 kS/s (e.g. `jackd -d dummy -r 96000 -C 16 -P 8`; "
                "JACK_DEFAULT_SERVER names it) and JACK-Client installed (pip install "
                "JACK-Client)?")

    def stderr_tail(self, lines: int = 1) -> str:
        """The last lines the client wrote to its standard error."""
        self._log.seek(0)
        return " | ".join(self._log.read()[-4000:].strip().splitlines()[-lines:])

    @property
    def pid(self) -> int:
        return self._proc.pid

    def _line(self, timeout_s: float) -> str:
        result: list[str] = []
        stdout = self._proc.stdout
        assert stdout is not None  # a pipe
        reader = threading.Thread(target=lambda: result.append(stdout.readline()), daemon=True)
        reader.start()
        reader.join(timeout_s)
        return result[0].strip() if result else ""

    def _send(self, command: dict) -> None:
        with self._lock:
            if self._proc.poll() is not None:
                raise WorldStartError(f"the simulated world's JACK client {self.name!r} has "
                                      f"ended ({self._proc.returncode})")
            assert self._proc.stdin is not None
            self._proc.stdin.write(json.dumps(command) + "\n")
            self._proc.stdin.flush()
            reply = self._line(REPLY_TIMEOUT_S)
        if reply != "ok":
            raise WorldStartError(f"the simulated world's JACK client answered {reply!r} to "
                                  f"{command['op']}")

    def perform(self, instruction: Instruction) -> None:
        self._send({"op": "perform", "instruction": instruction.model_dump(mode="json")})

    def live(self, on: bool) -> None:
        self._send({"op": "live", "on": on})

    def stall(self, seconds: float) -> None:
        self._send({"op": "stall", "seconds": seconds})

    def close(self) -> None:
        if self._proc.stdin is not None and not self._proc.stdin.closed:
            try:
                self._proc.stdin.close()
            except OSError:
                pass
        try:
            self._proc.wait(10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(10)


if __name__ == "__main__":
    _serve(sys.argv[1], sys.argv[2])
