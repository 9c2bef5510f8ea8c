"""One open session in the daemon: the operator the sequencer waits on, and the quality gate.

The capture sequencer is single-threaded and blocks in `Operator.perform` until the step's
set-up is ready. Here `perform` is where the daemon serves its sockets: it publishes the
instruction, then answers requests until the operator's `capture` (or hands-free) says go.
Between the files of a step (after every burst and image) the run serves the sockets again
without waiting, judges what was just written and, when it must, interrupts the step by raising:
the sequencer then journals the attempt as abandoned and the daemon decides what comes next
(an automatic retry, waiting for the operator, or closing the session).
"""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from daq import DaqError

from acquisition.contracts.camera import Camera, CameraError
from acquisition.contracts.capture_config import CaptureConfig, column_name
from acquisition.contracts.instructions import Instruction, InstructionKind
from ..sequencer import CaptureSequencer, Progress, plan_steps
from acquisition.contracts.session import SessionWriter
from acquisition.contracts.session._layout import attempt_dir
from acquisition.contracts.step_ids import REFMIC_STEP, is_pose_step
from kernel.stimulus import mls_length
from .config import DaemonConfig
from .hardware import Hardware
from .previews import Previews
from acquisition.contracts.protocol import (
    CameraPoses,
    CaptureEvent,
    CheckerboardEvent,
    ErrorEvent,
    InstructionEvent,
    LastCapture,
    LevelsEvent,
    PoseOutline,
    ProgressEvent,
    WarningEvent,
)
from .quality import (
    Failure,
    board_outline,
    checkerboard_corners,
    dead_channels,
    judge_images,
    judge_recording,
    low_snr_channels,
    measure,
)
from .states import WAITING_STATE_FOR, State, StateMachine

QUALITY_FILE = "quality.json"
MAX_COVERAGE = 1000
"""The most pose outlines `status` carries (the most recent ones)."""


class SessionEnding(Exception):
    """Unwinds the sequencer to end the session: close it for good with `exit_status`
    "success" or "aborted", or ("interrupted", on SIGTERM) release it without a stop record,
    resumable exactly as after a crash.

    `after_burst`: interrupt a step in progress after its current burst (abort, SIGTERM: the
    sequencer journals the attempt as abandoned); otherwise the session ends before the next
    step begins (stop).
    """

    def __init__(self, exit_status: Literal["success", "aborted", "interrupted"], reason: str,
                 after_burst: bool) -> None:
        super().__init__(reason)
        self.exit_status = exit_status
        self.reason = reason
        self.after_burst = after_burst


class CaptureInterrupted(Exception):
    """The step in progress is given up (the operator asked to redo it); capture it again."""


class QualityRetry(CaptureInterrupted):
    """A quality check with the retry policy failed; the attempt is abandoned."""


class Host(Protocol):
    """What a run needs from the daemon: its sockets, its events and its state machine."""

    machine: StateMachine
    previews: Previews

    def service(self, timeout_s: float) -> None: ...

    def publish(self, event_type: type, **fields: Any) -> None: ...

    def step_completed(self, step: str) -> None: ...


@dataclass
class _Attempt:
    """What the quality gate learned about the attempt in progress."""

    step: str
    found: dict[str, bool] = field(default_factory=dict)
    outlines: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    files: dict[str, dict[str, Any]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


@dataclass
class _Stillness:
    """Hands-free: how long the checkerboard has rested in camera 0's view."""

    next_look: float = 0.0
    corners: np.ndarray | None = None
    since: float | None = None


def _is_view_step(step: str) -> bool:
    """Whether `step`'s camera images are board views for the camera calibration (see
    calibration.camera.camera_calibration.calibrate_session: the poses' and the refmic image)."""
    return step == REFMIC_STEP or is_pose_step(step)


def _rounded(values: np.ndarray) -> list[float]:
    return [round(float(v), 1) for v in values]


class SessionRun:
    """Drives the capture of one open session for the daemon (see the module docstring)."""

    def __init__(self, host: Host, hardware: Hardware, writer: SessionWriter,
                 config: DaemonConfig, created_utc: Any) -> None:
        self.host = host
        self.hardware = hardware
        self.writer = writer
        self.config = config
        self.created_utc = created_utc
        self.capture = CaptureConfig.of_session(writer.capture, writer.path)
        plan = plan_steps(self.capture)
        self.steps_total = len(plan)
        self._view_steps = [s.id for s in plan if _is_view_step(s.id)]
        assert hardware.group is not None  # the daemon refuses a capture without every board
        self.sequencer = CaptureSequencer(
            self.capture, hardware.group, hardware.cameras, operator=self,
            writer=_ObservedWriter(writer, self),
            on_progress=self._on_progress, camera_timeout_s=config.camera_timeout_s,
            air_sensor=hardware.air_sensor)
        columns = self.capture.columns
        self._mics = [j for j, c in enumerate(columns) if c.role == "mic"]
        self._reference = [j for j, c in enumerate(columns) if c.role == "reference"]
        self._names = [column_name(c.role, c.mic_id, c.board, c.channel) for c in columns]
        self.step: str | None = None
        self.instruction: Instruction | None = None
        self.paused = False
        self.held = False
        self.redo = False
        self.ending: SessionEnding | None = None
        self.captures_requested = 0
        self.last_capture: LastCapture | None = None
        self._pending: str | None = None  # why the next capture may go ahead
        self._retries_left = config.quality.auto_retries
        self._attempt: _Attempt | None = None
        self._still = _Stillness()
        self.camera_poses: Counter[str] = Counter()
        self.camera_views: Counter[str] = Counter()
        self.coverage: list[PoseOutline] = []
        self._count_completed_poses()

    def _count_completed_poses(self) -> None:
        """The board views and camera-0 outlines of the poses (and the refmic image) completed
        before this run (a resumed session), from their quality.json."""
        for step, attempt in self.completed().items():
            if not _is_view_step(step):
                continue
            try:
                quality = json.loads((self.path / attempt_dir(step, attempt)
                                      / QUALITY_FILE).read_bytes())
                found = {str(k): bool(v) for k, v in quality["checkerboard_found"].items()}
                outline = quality.get("board_outline", {}).get(self.capture.cameras[0].name)
                pose = PoseOutline(step=step, outline=outline) if outline else None
            except (OSError, ValueError, KeyError, TypeError, AttributeError):
                continue  # a quality.json of another version: it only counts for the display
            self._count_views(step, found, pose)

    def _count_views(self, step: str, found: dict[str, bool],
                     outline: PoseOutline | None) -> None:
        """Count a completed step's board views (the calibration uses the refmic image's as
        well as the poses'), and a pose's outline in camera 0."""
        seen = [name for name, ok in found.items() if ok]
        self.camera_views.update(seen)
        if is_pose_step(step):
            self.camera_poses.update(seen)
        if outline is not None:
            self.coverage = [*self.coverage[-(MAX_COVERAGE - 1):], outline]

    def cameras_seen(self) -> list[CameraPoses]:
        """Completed poses with the board found, by camera (every camera, in order), with the
        board views the camera calibration gets so far and the steps left that may add one."""
        done = self.completed()
        left = sum(step not in done for step in self._view_steps)
        return [CameraPoses(camera=c.name, poses_seen=self.camera_poses[c.name],
                            board_views=self.camera_views[c.name], views_left=left)
                for c in self.capture.cameras]

    # -- what the daemon asks ---------------------------------------------------------------

    @property
    def session_id(self) -> str:
        return self.writer.session_id

    @property
    def path(self) -> Path:
        return self.writer.path

    def completed(self) -> dict[str, int]:
        return self.writer.completed_steps()

    @property
    def next_step(self) -> str:
        """The step being waited for or captured, else the first one still to capture."""
        if self.step is not None:
            return self.step
        remaining = self.sequencer.remaining_steps()
        return remaining[0].id if remaining else ""

    def ready(self) -> bool:
        """Whether the daemon should call `advance` (False: wait for the operator first)."""
        return not self.held or self.ending is not None

    def request_capture(self, why: str) -> int:
        """The operator's go for the current step; returns the capture's number."""
        self.captures_requested += 1
        self._pending = why
        self.held = False
        self._retries_left = self.config.quality.auto_retries
        return self.captures_requested

    def waiting_state(self) -> State:
        """The state for waiting on the current step (paused if the operator paused)."""
        if self.paused:
            return State.PAUSED
        assert self.instruction is not None
        return WAITING_STATE_FOR[self.instruction.kind]

    def advance(self) -> bool:
        """Run the sequencer; True when the session is closed, False when a capture failed."""
        try:
            if self.ending is not None:
                raise self.ending
            self.sequencer.run()  # stops the session as complete after the last step
        except SessionEnding as ending:
            if ending.exit_status == "interrupted":
                self.writer.close()
            else:
                self.writer.stop(ending.exit_status, ending.reason)
            return True
        except (CaptureInterrupted, CameraError, DaqError) as exc:
            self._failed(exc)
            return False
        return True

    # -- Operator: wait for the set-up -------------------------------------------------------

    def perform(self, instruction: Instruction) -> None:
        self.step = self.sequencer.remaining_steps()[0].id
        self.instruction = instruction
        self._check_ending()
        if self.hardware.world_operator is not None:
            self.hardware.world_operator.perform(instruction)
        self.host.publish(InstructionEvent, step=self.step, kind=instruction.kind.value,
                          text=instruction.text)
        self.host.machine.go(self.waiting_state(), f"next step {self.step}")
        self._still = _Stillness()
        while True:
            self._check_ending()
            if self._pending is not None and not self.paused:
                why, self._pending = self._pending, None
                self.host.machine.go(State.CAPTURING, f"{why}: {self.step}")
                return
            self.host.service(self.config.poll_interval_s)

    def _check_ending(self) -> None:
        if self.ending is not None:
            raise self.ending

    # -- hands-free ------------------------------------------------------------------------

    def hands_free_tick(self) -> None:
        """Capture a pose by itself once the board has rested in camera 0's view long enough."""
        hf = self.config.hands_free
        if (not hf.enabled or self._pending is not None or self.held
                or self.host.machine.state is not State.WAITING_FOR_POSE):
            return
        now = time.monotonic()
        if now < self._still.next_look:
            return
        self._still.next_look = now + hf.check_interval_s
        camera: Camera = self.hardware.cameras[0]
        try:
            image = camera.grab(self.config.camera_timeout_s).image
        except CameraError:
            self._still = _Stillness(next_look=self._still.next_look)
            return
        corners = checkerboard_corners(image, (self.capture.rig.corners_x,
                                               self.capture.rig.corners_y))
        previous, self._still.corners = self._still.corners, corners
        if corners is None:
            self._still.since = None
            return
        moved = (previous is None
                 or float(np.abs(corners - previous).max()) > hf.max_motion_px)
        if moved or self._still.since is None:
            self._still.since = now
        elif now - self._still.since >= hf.still_s:
            self.request_capture(f"hands-free (board still for {hf.still_s:g} s)")

    # -- the quality gate: called by _ObservedWriter ----------------------------------------

    def on_begin(self, step: str) -> None:
        self._attempt = _Attempt(step)

    def on_image(self, step: str, name: str, image: np.ndarray) -> None:
        attempt = self._current(step)
        camera = name.removesuffix(".png")
        rig = self.capture.rig
        pattern = (rig.corners_x, rig.corners_y)
        corners = checkerboard_corners(image, pattern)
        found = corners is not None
        attempt.found[camera] = found
        if corners is not None:
            attempt.outlines[camera] = board_outline(corners, pattern, image.shape[1],
                                                     image.shape[0])
        self.host.publish(CheckerboardEvent, step=step, camera=camera, found=found)
        self.host.previews.show(camera, image, corners, step)
        if len(attempt.found) == len(self.hardware.cameras):
            self._apply(judge_images(attempt.found, self.config.quality), step)
        self._checkpoint()

    def on_recording(self, step: str, name: str, codes: np.ndarray) -> None:
        attempt = self._current(step)
        burst = self.capture.burst
        levels = measure(codes, burst.pre_samples, mls_length(burst.mls_order),
                         self.config.quality.clip_fraction)
        summary = {"rms_dbfs": _rounded(levels.rms_dbfs), "peak_dbfs": _rounded(levels.peak_dbfs),
                   "snr_db": _rounded(levels.snr_db) if levels.snr_db is not None else [],
                   "clipped_channels": levels.clipped}
        attempt.files[name] = summary
        kind = self.instruction.kind if self.instruction else None
        reference = kind is InstructionKind.REFERENCE_AT_SPEAKER
        listening = self._reference if reference else self._mics
        quality = self.config.quality
        dead = [] if reference else dead_channels(levels, self._mics, quality)
        self.host.publish(LevelsEvent, step=step, file=name, **summary, listening=listening,
                          dead_channels=dead,
                          low_snr_channels=low_snr_channels(levels, listening, dead, quality))
        self._apply(judge_recording(levels, listening, self._mics, check_dead=not reference,
                                    config=quality, names=self._names), step)
        self._checkpoint()

    def before_end(self, step: str) -> None:
        attempt = self._current(step)
        self.writer.write_json(step, QUALITY_FILE, {
            "checkerboard_found": attempt.found, "board_outline": attempt.outlines,
            "recordings": attempt.files, "warnings": attempt.warnings})

    def after_end(self, step: str) -> None:
        attempt = self._current(step)
        if _is_view_step(step):
            outline = attempt.outlines.get(self.capture.cameras[0].name)
            self._count_views(step, attempt.found, PoseOutline(step=step, outline=outline)
                              if outline and is_pose_step(step) else None)
        self.host.publish(CaptureEvent, step=step, outcome="complete",
                          reason="; ".join(attempt.warnings))
        self.last_capture = LastCapture(number=self.captures_requested, step=step,
                                        outcome="complete", warnings=attempt.warnings)
        self._attempt = None
        self.host.step_completed(step)

    def on_abandon(self, step: str, reason: str) -> None:
        self.host.publish(CaptureEvent, step=step, outcome="abandoned", reason=reason)
        self._attempt = None

    def _current(self, step: str) -> _Attempt:
        if self._attempt is None or self._attempt.step != step:
            self._attempt = _Attempt(step)
        return self._attempt

    def _apply(self, failures: list[Failure], step: str) -> None:
        """Warn about the failures to keep; raise QualityRetry for those to capture again."""
        retry = [f for f in failures if f.policy == "retry"]
        for f in failures:
            if f.policy == "warn":
                self._current(step).warnings.append(f"{f.check}: {f.message}")
            self.host.publish(WarningEvent, step=step, check=f.check, message=f.message)
        if retry:
            raise QualityRetry("; ".join(f"{f.check}: {f.message}" for f in retry))

    def _checkpoint(self) -> None:
        """Between two files: answer requests, then stop the step if asked to."""
        self.host.service(0.0)
        if self.ending is not None and self.ending.after_burst:
            raise self.ending
        if self.redo:
            raise CaptureInterrupted("redo requested by the operator")

    def _on_progress(self, progress: Progress) -> None:
        done = self.completed()
        last = self.coverage[-1] if self.coverage else None
        self.host.publish(ProgressEvent, steps_done=progress.done, steps_total=progress.total,
                          poses_done=sum(is_pose_step(s) for s in done),
                          n_poses=self.capture.n_poses, step=progress.step,
                          cameras=self.cameras_seen(),
                          outline=last if last is not None and last.step == progress.step
                          else None)

    def _failed(self, exc: Exception) -> None:
        """After an abandoned attempt: retry by itself, or wait for the operator's capture."""
        reason = str(exc) if isinstance(exc, CaptureInterrupted) else f"{type(exc).__name__}: {exc}"
        redo, self.redo = self.redo, False
        if isinstance(exc, QualityRetry) and self._retries_left > 0:
            self._retries_left -= 1
            self._pending = "automatic retry"
            return
        self.held = True
        self.last_capture = LastCapture(number=self.captures_requested, step=self.step or "",
                                        outcome="abandoned", reason=reason)
        what = "set up again and" if redo else "fix the cause, then"
        self.host.publish(WarningEvent if redo else ErrorEvent, step=self.step,
                          message=f"capture of {self.step} abandoned ({reason}); {what} capture "
                                  "it again")
        self.host.machine.go(self.waiting_state(), f"capture of {self.step} abandoned")


class _ObservedWriter:
    """The session writer as the sequencer sees it, with the quality gate between the calls."""

    def __init__(self, writer: SessionWriter, run: SessionRun) -> None:
        self._writer = writer
        self._run = run

    def completed_steps(self) -> dict[str, int]:
        return self._writer.completed_steps()

    def begin_step(self, step: str) -> int:
        attempt = self._writer.begin_step(step)
        self._run.on_begin(step)
        return attempt

    def write_image(self, step: str, name: str, image: np.ndarray,
                    meta: dict | None = None) -> Path:
        path = self._writer.write_image(step, name, image, meta)
        self._run.on_image(step, name, image)
        return path

    def write_recording(self, step: str, name: str, codes: np.ndarray, sample_rate_hz: int,
                        meta: dict | None = None) -> Path:
        path = self._writer.write_recording(step, name, codes, sample_rate_hz, meta)
        self._run.on_recording(step, name, codes)
        return path

    def write_json(self, step: str, name: str, data: dict) -> Path:
        return self._writer.write_json(step, name, data)

    def end_step(self, step: str) -> None:
        self._run.before_end(step)
        self._writer.end_step(step)
        self._run.after_end(step)

    def abandon_step(self, step: str, reason: str) -> None:
        self._writer.abandon_step(step, reason)
        self._run.on_abandon(step, reason)

    def stop(self, exit_status: str = "success", reason: str = "") -> None:
        self._writer.stop(exit_status, reason)

    def close(self) -> None:
        self._writer.close()

