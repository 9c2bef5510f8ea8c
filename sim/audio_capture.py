"""A simulated capture on the audio backend: the world played by a JACK client (sim.jack_world)
between the ports of a real audio server, recorded through PortAudio by `daq.audio`.

The cameras render this process's copy of the world; the sound comes from the JACK client's
copy, built from the same options (the same seed: the same array, poses and gains). The
operator sets both up alike (`RelayOperator`). The capture configuration is that of one
16-input, 8-output audio interface: microphone m on input m, the reference microphone on the
input after the last microphone, speaker k on output k, full scale at `RANGE_V` volts.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from itertools import count
from typing import Literal

import numpy as np

from acquisition.contracts.burst import BurstConfig
from acquisition.contracts.camera import Camera
from acquisition.contracts.capture_config import (
    BoardEntry,
    CameraEntry,
    CaptureConfig,
    ColumnEntry,
    ReferenceMicEntry,
    SpeakerEntry,
)
from acquisition.contracts.instructions import Instruction
from daq import InputChannel, OutputChannel, SyncGroup
from daq.audio import AudioConfig, AudioDeviceConfig, open_audio_boards

from .analog_bench import AcousticBench
from .audio_world import RANGE_V
from .cameras import SimulatedCamera
from .capture import SimulatedCapture, SimulationOptions, nominal_layout, rig_entry, world_for
from .geometry import RigidTransform
from .jack_world import MIC_PORTS, SPEAKER_PORTS, WorldProcess
from .setups import Setups
from .simulated_operator import SimulatedOperator, reference_stand_position
from .world import World

DEVICE_LABEL = "world"
"""The board serial of the world's interface in the capture configuration."""
LATENCY_SAMPLES = 4096
"""Recorded after each burst on top of the simulated boards' `post_samples`: an audio server's
output-to-input latency (here JACK's, one period: up to 4096 frames, 43 ms at 96 kS/s) comes
before the burst's arrival, and a recording that ends inside the burst fails its quality
check."""
_names = count()


class RelayOperator(SimulatedOperator):
    """Sets up this process's world (the cameras) and the JACK client's (the sound) alike."""

    def __init__(self, world: World, poses: Sequence[RigidTransform],
                 stand_position_m: np.ndarray, setups: Setups, process: WorldProcess) -> None:
        super().__init__(world, poses, stand_position_m, setups)
        self.process = process

    def perform(self, instruction: Instruction) -> None:
        super().perform(instruction)
        self.process.perform(instruction)


def audio_capture_config(world: World, n_poses: int, burst: BurstConfig,
                         cameras: Sequence[Camera], label: str = DEVICE_LABEL) -> CaptureConfig:
    """The capture configuration of the world's interface (module docstring)."""
    n_mics, rig = world.layout.n_mics, world.rig
    n_speakers = rig.n_speakers
    if n_mics + 1 > MIC_PORTS or n_speakers > SPEAKER_PORTS:
        raise ValueError(f"{n_mics} microphones and the reference, {n_speakers} speakers: an "
                         f"interface of {MIC_PORTS} inputs and {SPEAKER_PORTS} outputs holds "
                         "15 and 8 at most (--array scatter15)")
    role: list[tuple[Literal["mic", "reference"], int | None]] = [
        *(("mic", m) for m in range(n_mics)), ("reference", None)]
    return CaptureConfig(
        sample_rate_hz=world.sample_rate_hz,
        boards=(BoardEntry(model="audio", serial=label,
                           inputs=tuple(InputChannel(channel=j, range_v=RANGE_V)
                                        for j in range(n_mics + 1)),
                           outputs=tuple(OutputChannel(channel=k, range_v=RANGE_V)
                                         for k in range(n_speakers))),),
        columns=tuple(ColumnEntry(board=label, channel=j, range_v=RANGE_V, role=r, mic_id=m)
                      for j, (r, m) in enumerate(role)),
        speakers=tuple(SpeakerEntry(index=k, board=label, output_channel=k,
                                    rig_position_m=tuple(rig.speakers_m[k]))
                       for k in range(n_speakers)),
        reference=ReferenceMicEntry(board=label, channel=n_mics),
        burst=burst,
        rig=rig_entry(rig),
        cameras=tuple(CameraEntry(name=c.name, device_id=c.device_id) for c in cameras),
        n_poses=n_poses,
        layout=nominal_layout(world.layout),
    )


def build_audio_capture(options: SimulationOptions) -> SimulatedCapture:
    """The world of `options` as a JACK client, its interface opened by `daq.audio`, the
    cameras on this process's world (module docstring). Needs a running JACK server
    (JACK_DEFAULT_SERVER names it) at the world's rate."""
    if options.lab_effects().names:
        raise ValueError("the audio backend's world is the ideal lab (sim.audio_world): "
                         "simulate it with --lab ideal and no --effect")
    world, poses = world_for(options)
    setups = Setups()
    cameras: list[Camera] = [SimulatedCamera(m, world, i, setups)
                             for i, m in enumerate(world.layout.cameras)]
    burst = options.burst(world.sample_rate_hz)
    burst = burst.model_copy(update={"post_samples": burst.post_samples + LATENCY_SAMPLES})
    config = audio_capture_config(world, options.poses, burst, cameras)
    name = f"micam-world-{os.getpid()}-{next(_names)}"
    process = WorldProcess(options.model_dump_json(), name)
    try:
        audio = AudioConfig(devices=(AudioDeviceConfig(label=DEVICE_LABEL, name=name),))
        group = SyncGroup(open_audio_boards(audio, [DEVICE_LABEL]))
    except BaseException:
        process.close()
        raise
    operator = RelayOperator(world, poses, reference_stand_position(world.layout.cameras[0]),
                             setups, process)
    return SimulatedCapture(options, world, AcousticBench(world, setups), group, cameras,
                            operator, config, poses, None, world_process=process)
