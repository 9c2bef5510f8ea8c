"""The hardware the daemon drives: real boards and V4L2 cameras, or the simulated world.

Either way the daemon gets a sync group, cameras and a capture configuration. The simulated
world also brings its operator (who moves the simulated rig when the daemon asks for a new
set-up; a person does that on the real rig) and its ground truth, stored with each session.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

from daq import SyncGroup

from ..air import AirSensor
from ..camera import Camera
from ..capture_config import CaptureConfig
from ..operator import Operator
from .config import DaemonConfig, HardwareConfig, SimulationConfig

log = logging.getLogger("micam.daemon")

TRUTH_FILE = "truth.json"


@dataclass
class Hardware:
    """What the daemon captures with.

    Attributes:
        config: the capture configuration, with the configured number of poses.
        group: the boards, on a shared clock and trigger.
        cameras: in the configuration's order.
        world_operator: sets the simulated world up for each instruction; None on real hardware.
        max_poses: the most poses a session may have (the simulated world has a fixed list).
        session_files: top-level JSON files written into every new session (the ground truth).
        description: for the log and `status`.
        air_sensor: reads the air beside the array at every pose (None: no sensor).
        live_scene: the simulated world's sources start (True) or stop (False) playing, for
            live mode; None on real hardware (the room plays what it plays).
    """

    config: CaptureConfig
    group: SyncGroup
    cameras: list[Camera]
    world_operator: Operator | None = None
    max_poses: int | None = None
    session_files: dict[str, dict] = field(default_factory=dict)
    description: str = ""
    air_sensor: AirSensor | None = None
    live_scene: Callable[[bool], None] | None = None

    @property
    def simulated(self) -> bool:
        return self.world_operator is not None

    def close(self) -> None:
        self.group.close()
        for camera in self.cameras:
            camera.close()


def _simulated(options: SimulationConfig) -> Hardware:
    from sim.capture import build_simulated_capture, truth_document
    from sim.live_scene import demo_scene

    sim = build_simulated_capture(options)
    world = sim.world

    def live_scene(playing: bool) -> None:
        world.live_scene = demo_scene(world) if playing else None

    return Hardware(
        config=sim.config, group=sim.group, cameras=sim.cameras, world_operator=sim.operator,
        max_poses=options.poses, session_files={TRUTH_FILE: truth_document(sim)},
        air_sensor=sim.air_sensor, live_scene=live_scene,
        description=f"simulated world ({options.array}, {options.poses} poses, seed "
                    f"{options.seed})")


def _real(hw: HardwareConfig) -> Hardware:
    from daq.usb import open_boards

    from ..cameras_v4l2 import V4L2Camera

    boards = open_boards([b.serial for b in hw.capture.boards], firmware_dir=hw.firmware_dir)
    cameras: list[Camera] = []
    try:
        for c in hw.cameras:
            cameras.append(V4L2Camera(c.name, c.device, width=c.width, height=c.height,
                                      fourcc=c.fourcc, fps=c.fps, exposure=c.exposure))
    except BaseException:
        for board in boards:
            board.close()
        for camera in cameras:
            camera.close()
        raise
    return Hardware(config=hw.capture, group=SyncGroup(boards), cameras=cameras,
                    description=f"{len(boards)} boards, {len(cameras)} V4L2 cameras")


def open_hardware(config: DaemonConfig) -> Hardware:
    """Open the configured hardware, or build the simulated world when none is configured."""
    hardware = _simulated(config.simulation) if config.hardware is None else _real(config.hardware)
    log.info("hardware: %s", hardware.description)
    return hardware
