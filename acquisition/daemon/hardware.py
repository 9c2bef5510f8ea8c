"""The hardware the daemon drives, and how the real kind is opened (boards or audio interfaces,
and V4L2 cameras).

Either way the daemon gets a sync group, cameras and a capture configuration. The simulated
world, built by the application (`micam.hardware`), also brings its operator (who moves the
simulated rig when the daemon asks for a new set-up; a person does that on the real rig) and
its ground truth, stored with each session.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from daq import Board, SyncGroup

from acquisition.contracts.air import AirSensor
from acquisition.contracts.camera import Camera
from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.instructions import Operator
from .config import HardwareConfig


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
        closers: called last by `close` (the simulated world's JACK client ends).
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
    closers: list[Callable[[], None]] = field(default_factory=list)

    @property
    def simulated(self) -> bool:
        return self.world_operator is not None

    def close(self) -> None:
        self.group.close()
        for camera in self.cameras:
            camera.close()
        for close in self.closers:
            close()

    def __enter__(self) -> Hardware:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _open_boards(hw: HardwareConfig) -> list[Board]:
    """The configured boards, in the capture configuration's order, on the chosen backend."""
    serials = [b.serial for b in hw.capture.boards]
    if hw.backend == "audio":
        from daq.audio import open_audio_boards

        assert hw.audio is not None  # HardwareConfig's validator
        return list(open_audio_boards(hw.audio, serials))
    from daq.usb import open_boards

    return list(open_boards(serials, firmware_dir=hw.firmware_dir))


def open_real_hardware(hw: HardwareConfig) -> Hardware:
    """Open the configured boards (one sync group) and V4L2 cameras; nothing stays open on error."""
    from ..cameras_v4l2 import V4L2Camera

    boards = _open_boards(hw)
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
    kind = "audio interfaces" if hw.backend == "audio" else "boards"
    return Hardware(config=hw.capture, group=SyncGroup(boards), cameras=cameras,
                    description=f"{len(boards)} {kind}, {len(cameras)} V4L2 cameras")
