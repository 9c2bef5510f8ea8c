"""The foreign lab of docs/import.md's worked example (sim/foreign_lab.py writes its folder, as
`micam example import DIR` does), and `same_world_natively`, which records the same world
(microphones, camera, rig, poses, air) with micam's own acquisition on the simulated hardware,
for the comparison (here, not in sim/: it drives the capture sequencer, which sim must not
import).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sim.foreign_lab import (
    CHANNELS_PER_BOARD,
    EXTRA_RECORDED,
    FS,
    HUMIDITY,
    MLS_ORDER,
    N_BOARDS,
    N_MICS,
    SILENCE_AFTER,
    SILENCE_BEFORE,
    TEMPERATURE_C,
    ForeignWorld,
)


def same_world_natively(world: ForeignWorld, session: Path) -> dict:
    """The same microphones, camera, rig, poses and air captured by micam's own acquisition
    (the capture sequencer on simulated boards: 3 DT9836-6-2 driving the speakers and 5
    DT9816-A, 6 microphones each, and the reference microphone on a DT9816-A of its own,
    recorded on every burst, with its image on the stand). Returns its truth."""
    from acquisition.contracts.burst import BurstConfig
    from acquisition.contracts.camera import Camera
    from acquisition.sequencer import CaptureSequencer
    from acquisition.contracts.session import SessionWriter
    from daq import SyncGroup
    from sim.arrays import ArrayLayout, BoardSpec, ChannelRef
    from sim.analog_bench import AcousticBench
    from sim.boards import SimulatedBoard
    from sim.cameras import SimulatedCamera
    from sim.capture import capture_config_for
    from sim.geometry import Rig, pinhole
    from sim.simulated_operator import SimulatedOperator, reference_stand_position
    from sim.world import World

    specs = ([BoardSpec("DT9836-6-2", str(36101 + b)) for b in range(3)]
             + [BoardSpec("DT9816-A", str(16101 + b)) for b in range(5)]
             + [BoardSpec("DT9816-A", "16199")])
    camera = pinhole("cam0")
    layout = ArrayLayout(
        name="foreign48", mic_positions_m=world.mics_m,
        mic_normals=np.tile([0.0, 0.0, 1.0], (N_MICS, 1)), cameras=(camera,),
        boards=tuple(specs),
        mic_inputs=tuple(ChannelRef(m // CHANNELS_PER_BOARD, m % CHANNELS_PER_BOARD)
                         for m in range(N_MICS)),
        speaker_outputs=tuple(ChannelRef(b, ch) for b in range(3) for ch in range(2)),
        reference_input=ChannelRef(N_BOARDS, 0))
    rig = Rig(origin_square="light")
    sim_world = World(layout=layout, rig=rig, temperature_c=TEMPERATURE_C,
                      relative_humidity=HUMIDITY, sample_rate_hz=FS, seed=world.seed)
    bench = AcousticBench(sim_world)
    cameras: list[Camera] = [SimulatedCamera(camera, sim_world, 0)]
    operator = SimulatedOperator(sim_world, world.poses, reference_stand_position(camera, 0.6))
    config = capture_config_for(
        layout, rig, len(world.poses), FS,
        BurstConfig(mls_order=MLS_ORDER, pre_samples=SILENCE_BEFORE,
                    post_samples=SILENCE_AFTER + EXTRA_RECORDED), cameras)
    writer = SessionWriter.create(session, capture=config.model_dump(mode="json"))
    CaptureSequencer(config, SyncGroup([SimulatedBoard(s, bench) for s in specs]), cameras,
                     operator, writer).run()
    truth = {
        "microphones": [{"id": m, "position_m": world.mics_m[m].tolist()}
                        for m in range(N_MICS)],
        "speed_of_sound_m_s": sim_world.speed_of_sound_m_s,
        "cameras": [camera.to_json()],
        "board_latencies_s": {s.serial: float(lat) for s, lat in
                              zip(specs, sim_world.board_latencies_s, strict=True)},
    }
    (session / "truth.json").write_text(json.dumps(truth))
    return truth
