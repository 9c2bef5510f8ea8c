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

from acquisition.contracts.camera import Camera
from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.instructions import Operator
from kernel.air import AirSensor
from .config import ConfigError, HardwareConfig


@dataclass
class Hardware:
    """What the daemon captures with.

    Attributes:
        config: the capture configuration, with the configured number of poses.
        group: the boards, on a shared clock and trigger; None with the cameras alone.
        cameras: in the configuration's order.
        world_operator: sets the simulated world up for each instruction; None on real hardware.
        max_poses: the most poses a session may have (the simulated world has a fixed list).
        session_files: top-level JSON files written into every new session (the ground truth).
        description: for the log and `status`.
        air_sensor: reads the air beside the array at every pose (None: no sensor).
        live_scene: the simulated world's sources start (True) or stop (False) playing, for
            live mode; None on real hardware (the room plays what it plays).
        closers: called last by `close` (the simulated world's JACK client ends).
        boards_left_out: boards of `config` not brought up (`only_boards`): captures and live
            mode, which record every column of `config`, are refused.
    """

    config: CaptureConfig
    group: SyncGroup | None
    cameras: list[Camera]
    world_operator: Operator | None = None
    max_poses: int | None = None
    session_files: dict[str, dict] = field(default_factory=dict)
    description: str = ""
    air_sensor: AirSensor | None = None
    live_scene: Callable[[bool], None] | None = None
    closers: list[Callable[[], None]] = field(default_factory=list)
    boards_left_out: tuple[str, ...] = ()

    @property
    def simulated(self) -> bool:
        return self.world_operator is not None

    def recording_refusal(self, what: str) -> str | None:
        """Why `what` (a capture, live mode), which records every board, cannot run; None when
        every board of the configuration is up."""
        if not self.boards_left_out:
            return None
        up = ([b.serial for b in self.config.boards if b.serial not in self.boards_left_out]
              if self.group is not None else [])
        running = f"with board {', '.join(up)} only" if up else "with the cameras alone"
        return (f"{what} needs every board of the configuration; this daemon runs {running} "
                f"(only_boards, `micam daemon --boards`), without "
                f"{', '.join(self.boards_left_out)}: restart it without --boards / "
                "--cameras-only once they are connected")

    def close(self) -> None:
        if self.group is not None:
            self.group.close()
        for camera in self.cameras:
            camera.close()
        for close in self.closers:
            close()

    def __enter__(self) -> Hardware:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def boards_to_bring_up(capture: CaptureConfig,
                       only: tuple[str, ...] | None) -> tuple[list[str], tuple[str, ...]]:
    """The serials to open, in the configuration's order (its first the clock master), and
    those left out, for `only_boards` (None: every board). ConfigError for a board `only`
    names that the configuration has not."""
    serials = [b.serial for b in capture.boards]
    if only is None:
        return serials, ()
    unknown = [s for s in only if s not in serials]
    if unknown:
        raise ConfigError(f"only_boards: no board {', '.join(unknown)} in the capture "
                          f"configuration; name some of {', '.join(serials)}, or none for the "
                          "cameras alone")
    return ([s for s in serials if s in only], tuple(s for s in serials if s not in only))


def _open_boards(hw: HardwareConfig, serials: list[str]) -> list[Board]:
    """The boards `serials` of the configuration, in its order, on the chosen backend."""
    if not serials:
        return []
    if hw.backend == "audio":
        from daq.audio import open_audio_boards

        assert hw.audio is not None  # HardwareConfig's validator
        return list(open_audio_boards(hw.audio, serials))
    from daq.usb import open_boards

    return list(open_boards(serials, firmware_dir=hw.firmware_dir))


def open_real_hardware(hw: HardwareConfig,
                       only_boards: tuple[str, ...] | None = None) -> Hardware:
    """Open the configured boards (one sync group; only `only_boards` when given, none with
    the cameras alone) and V4L2 cameras; nothing stays open on error."""
    from ..cameras_v4l2 import V4L2Camera

    serials, left_out = boards_to_bring_up(hw.capture, only_boards)
    boards = _open_boards(hw, serials)
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
    return Hardware(config=hw.capture, group=SyncGroup(boards) if boards else None,
                    cameras=cameras, boards_left_out=left_out,
                    description=f"{len(boards)} {kind}, {len(cameras)} V4L2 cameras"
                                + left_out_note(left_out))


def left_out_note(left_out: tuple[str, ...]) -> str:
    """The description's note of the boards not brought up."""
    return f" ({', '.join(left_out)} left out: no capture)" if left_out else ""


def keep_boards(hardware: Hardware, only_boards: tuple[str, ...] | None) -> Hardware:
    """`hardware` (all its boards open, e.g. the simulated world's) with only `only_boards`
    up: the others closed, the first kept one the clock master."""
    if only_boards is None:
        return hardware
    assert hardware.group is not None  # every board of the world is open
    serials, left_out = boards_to_bring_up(hardware.config, only_boards)
    kept = [b for b in hardware.group.boards if b.identity.serial in serials]
    for board in hardware.group.boards:
        if board.identity.serial not in serials:
            board.close()
    hardware.group = SyncGroup(kept) if kept else None
    hardware.boards_left_out = left_out
    hardware.description += left_out_note(left_out)
    return hardware
