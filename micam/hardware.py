"""The composition root: real boards and cameras, or the simulated world, for the daemon.

The acquisition daemon knows only `Hardware` and the real devices; the simulated world lives in
`sim/`, which the daemon must not import (a daemon on the acquisition PC never loads the
simulator). This module joins them: `MicamDaemonConfig` is the daemon's configuration with the
`[simulation]` section, and `open_hardware` opens what the configuration asks for.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pydantic import ConfigDict

from acquisition.daemon.config import DaemonConfig, load_config
from acquisition.daemon.hardware import Hardware, open_real_hardware
from sim.capture import SimulationOptions

from .simulated import TRUTH_FILE

log = logging.getLogger("micam.daemon")


class SimulationConfig(SimulationOptions):
    """The simulated world the daemon runs on without hardware (unknown keys refused)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class MicamDaemonConfig(DaemonConfig):
    """The daemon's configuration as `micam daemon` reads it: with the simulated world's section
    (used when there is no `[hardware]`)."""

    simulation: SimulationConfig = SimulationConfig()


def load_daemon_config(path: Path | None = None) -> MicamDaemonConfig:
    """Read `micam daemon`'s configuration (None: defaults) with its environment overrides."""
    return load_config(path, MicamDaemonConfig)


def _simulated(options: SimulationConfig) -> Hardware:
    from sim.backends import build_capture
    from sim.capture import truth_document
    from sim.live_scene import demo_scene

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


def open_hardware(config: MicamDaemonConfig) -> Hardware:
    """Open the configured hardware, or build the simulated world when none is configured."""
    hardware = (_simulated(config.simulation) if config.hardware is None
                else open_real_hardware(config.hardware))
    log.info("hardware: %s", hardware.description)
    return hardware
