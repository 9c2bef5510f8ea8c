"""The daemon's commands for live mode (`live.start`, `live.stop`, `live.record`) and its turn
of the loop, around `acquisition.live.mode.LiveMode`.

Live mode is entered from idle only (never while a calibration session is open: the state
machine refuses it, and a session cannot start while live), and left by `live.stop`, by a
board's fault (an `error` event, then `live_mode` with the reason), or when the daemon stops.
Recordings go to `<session_root>.live/` (beside the sessions, so that they never appear in the
list of calibration sessions), one session-format directory each.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from daq import DaqError, GroupStream

from acquisition.contracts.errors import UserError

from ..live.mode import MAX_RING_BYTES, LiveFault, LiveMode, LiveOptions, ring_bytes
from .hardware import Hardware
from acquisition.contracts.protocol import (
    ErrorEvent,
    LiveModeEvent,
    LiveRecordArgs,
    LiveRecordResult,
    LiveStartArgs,
    LiveStatus,
)
from .server import Refusal
from .states import State, StateMachine

log = logging.getLogger("micam.daemon")

STEP = "live"


def live_root(session_root: Path) -> Path:
    """Where live recordings are written: beside the session root."""
    return session_root.with_name(session_root.name + ".live")


class LiveControl:
    """Live mode as the daemon runs it (module docstring)."""

    def __init__(self, hardware: Hardware, machine: StateMachine, session_root: Path,
                 publish: Callable[..., Any],
                 publish_frames: Callable[[str, list[bytes | memoryview]], None],
                 camera_timeout_s: float) -> None:
        self.hardware = hardware
        self.machine = machine
        self.root = live_root(session_root)
        self._publish = publish
        self._publish_frames = publish_frames
        self._timeout_s = camera_timeout_s
        self.mode: LiveMode | None = None

    def start(self, args: LiveStartArgs) -> LiveStatus:
        hw = self.hardware
        refusal = hw.recording_refusal("live mode")
        if refusal is not None:
            raise Refusal("wrong_state", refusal)
        assert hw.group is not None  # every board is up
        cameras = hw.cameras
        if args.cameras is not None:
            known = {c.name: c for c in hw.cameras}
            unknown = sorted(set(args.cameras) - set(known))
            if unknown:
                raise Refusal("bad_request", f"no camera {', '.join(unknown)}; the daemon has "
                                             f"{', '.join(known) or 'none'}")
            cameras = [known[name] for name in dict.fromkeys(args.cameras)]
        fs, n_columns = hw.config.sample_rate_hz, len(hw.config.columns)
        if ring_bytes(args.seconds, fs, n_columns) > MAX_RING_BYTES:
            most = MAX_RING_BYTES // (2 * n_columns) / fs
            raise Refusal("bad_request", f"{args.seconds:g} s of {n_columns} columns at "
                                         f"{fs:g} Hz do not fit the {MAX_RING_BYTES // 2**20} "
                                         f"MiB live mode keeps; ask for at most {most:.1f} s")
        mode = LiveMode(GroupStream(hw.group, hw.config.scan_configs()), cameras, hw.config,
                        LiveOptions(args.seconds, args.camera_fps, args.samples),
                        self._publish, self._publish_frames, self._timeout_s)
        if hw.live_scene is not None:
            hw.live_scene(True)
        try:
            mode.start()
        except DaqError as exc:
            if hw.live_scene is not None:
                hw.live_scene(False)
            raise Refusal("wrong_state", f"the boards cannot start live mode: {exc}") from None
        self.mode = mode
        self.machine.go(State.LIVE, f"live mode, {args.seconds:g} s kept")
        self._publish(LiveModeEvent, running=True, reason="live.start")
        return mode.status()

    def stop(self, reason: str = "live.stop") -> dict[str, Any]:
        """Leave live mode (no-op when not live)."""
        mode = self.mode
        if mode is None:
            return {"stopped": False}
        self.mode = None
        try:
            mode.stop()
        finally:
            if self.hardware.live_scene is not None:
                self.hardware.live_scene(False)
            self.machine.go(State.IDLE, reason)
            self._publish(LiveModeEvent, running=False, reason=reason)
        return {"stopped": True, "samples": mode.stream.index}

    def record(self, args: LiveRecordArgs) -> LiveRecordResult:
        mode = self._mode()
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            return mode.record(self.root, args.seconds)
        except (OSError, UserError) as exc:
            raise Refusal("session_error", f"cannot record under {self.root}: {exc}") from None

    def tick(self) -> None:
        """One turn while live: read, publish, take frames; a board's fault ends live mode."""
        mode = self.mode
        if mode is None:
            return
        try:
            mode.tick()
        except LiveFault as exc:
            log.error("%s", exc)
            self._publish(ErrorEvent, step=STEP, message=str(exc))
            self.stop(str(exc))

    def status(self) -> LiveStatus | None:
        return self.mode.status() if self.mode is not None else None

    def _mode(self) -> LiveMode:
        assert self.mode is not None, "check_allowed admits this command only while live"
        return self.mode
