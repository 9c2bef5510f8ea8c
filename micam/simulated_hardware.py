"""The simulated world as the daemon's hardware: its `[simulation]` section and its `Hardware`.

Imported (by `micam.hardware`) only when no `[hardware]` is configured: everything here loads
the simulator, which a daemon on the acquisition PC never does.
"""

from __future__ import annotations

from pydantic import ConfigDict

from acquisition.daemon.config import DaemonConfig
from acquisition.daemon.hardware import Hardware
from sim.backends import build_capture
from sim.capture import SimulationOptions, truth_document
from sim.live_scene import demo_scene

from .simulated import TRUTH_FILE


class SimulationConfig(SimulationOptions):
    """The simulated world the daemon runs on without hardware (unknown keys refused)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class MicamDaemonConfig(DaemonConfig):
    """The daemon's configuration as `micam daemon` reads it without `[hardware]`: with the
    simulated world's section, validated."""

    simulation: SimulationConfig = SimulationConfig()


def simulated_hardware(options: SimulationConfig) -> Hardware:
    """The simulated world of `options`: its boards, cameras, operator and air sensor."""
    sim = build_capture(options)
    world = sim.world
    process = sim.world_process

    def live_scene(playing: bool) -> None:
        world.live_scene = demo_scene(world) if playing else None
        if process is not None:  # the audio backend: the sound is the JACK client's
            process.live(playing)

    on = " through the audio backend" if process is not None else ""
    return Hardware(
        config=sim.config, group=sim.group, cameras=sim.cameras, world_operator=sim.operator,
        max_poses=options.poses, session_files={TRUTH_FILE: truth_document(sim)},
        air_sensor=sim.air_sensor, live_scene=live_scene,
        closers=[process.close] if process is not None else [],
        description=f"simulated world ({options.array}, {options.poses} poses, seed "
                    f"{options.seed}){on}")
