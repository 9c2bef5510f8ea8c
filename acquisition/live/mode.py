"""Live mode in the daemon: the boards scanning without end, the cameras streaming, the latest
seconds in a ring buffer, published to clients and recorded on request.

The daemon's loop calls `tick` on every turn (at least every `POLL_S` while live). A tick reads
what the clock says the boards have scanned since the last one, in blocks of `BLOCK_SAMPLES`
(at most `MAX_BLOCKS_PER_TICK`, so the sockets are served in between), appends them to the
ring, and publishes each block as a `samples` message (docs/protocol.md) for the clients that
image it; then it takes a frame of every camera that is due (`camera_fps`) and publishes it as
a `live_frame` event. A real board blocks in `read` until its samples are in; a simulated one
delivers at once, so pacing by the clock is what keeps both at real time. `behind_s` says how
far the reads trail the clock: a board's FIFO holds well under a second, so a daemon that
falls behind loses data, which the board reports as an overrun.

A board's error (an overrun, an unplugged board, lost alignment) ends live mode: the stream is
stopped, and the daemon publishes an `error` event and leaves the mode (`LiveFault`). A camera
that returns no frame is logged and tried again at the next frame.
"""

from __future__ import annotations

import base64
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from daq import DaqError, GroupStream

from acquisition.contracts.camera import Camera, CameraError
from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.errors import UserError
from ..preview_jpeg import encode_preview
from acquisition.contracts.protocol import (
    SAMPLES_TOPIC,
    LiveFrameEvent,
    LiveRecordedEvent,
    LiveRecordResult,
    LiveStatus,
    SamplesHeader,
)
from .record import ACOULAR_FILE, write_live_recording
from .ring import FrameRing, SampleRing, StampedFrame

log = logging.getLogger("micam.daemon")

BLOCK_SAMPLES = 2048
"""Samples per column read at a time (21 ms at 96 kS/s): the latency the reads add."""
MAX_BLOCKS_PER_TICK = 16
"""Blocks read in one turn of the loop at most, so that requests are served in between."""
POLL_S = 0.01
"""The longest the loop waits for requests while live."""
FRAME_WIDTH = 640
"""Width of the published camera frames, pixels."""
FRAME_QUALITY = 80
"""JPEG quality of the published camera frames."""
MAX_FRAME_BYTES = 512 * 2**20
"""The camera frames kept of the ring's seconds, bytes at most (full-size images: the newest
are kept, so a recording of the longest rings with many cameras has frames of its latest part
only)."""
MAX_RING_BYTES = 2**30
"""The time data kept, bytes at most: 30 s of 73 columns at 96 kS/s are 420 MB (live.start
asking for more is refused, see `ring_bytes`)."""


def ring_bytes(seconds: float, sample_rate_hz: float, n_columns: int) -> int:
    """The bytes of a ring of `seconds` of `n_columns` int16 columns."""
    return round(seconds * sample_rate_hz) * n_columns * 2


class LiveFault(Exception):
    """A board failed during live mode; the message names it. Live mode has stopped."""


@dataclass(frozen=True)
class LiveOptions:
    """See `LiveStartArgs` in the protocol."""

    seconds: float = 10.0
    camera_fps: float = 10.0
    samples: bool = True


class LiveMode:
    """One run of live mode (module docstring).

    Args:
        group_stream: the boards' endless scan (not started).
        cameras: the cameras, streamed at options.camera_fps.
        config: the capture configuration (columns, for recordings).
        options: ring length, frame rate, whether the time data is published.
        publish_event: the daemon's `publish` (event type, fields).
        publish_frames: the daemon's raw publisher (topic, frames).
        camera_timeout_s: for every grab.
        clock: monotonic seconds (tests may pass their own).
    """

    def __init__(self, group_stream: GroupStream, cameras: list[Camera], config: CaptureConfig,
                 options: LiveOptions, publish_event: Callable[..., Any],
                 publish_frames: Callable[[str, list[bytes | memoryview]], None],
                 camera_timeout_s: float = 2.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.stream = group_stream
        self.cameras = cameras
        self.config = config
        self.options = options
        self._publish_event = publish_event
        self._publish_frames = publish_frames
        self._timeout_s = camera_timeout_s
        self._clock = clock
        fs = group_stream.sample_rate_hz
        self.ring = SampleRing(group_stream.n_columns, round(options.seconds * fs))
        frames = max(1, round(options.seconds * options.camera_fps)) * max(1, len(cameras))
        self.frames = FrameRing(frames, MAX_FRAME_BYTES)
        self.n_frames = 0
        self.max_behind_s = 0.0
        self._t0 = 0.0
        self._next_frame = 0.0
        self._recorders: list[threading.Thread] = []
        self._written: list[tuple[Path, str]] = []  # recordings finished, not yet announced

    @property
    def sample_rate_hz(self) -> float:
        return self.stream.sample_rate_hz

    def start(self) -> None:
        self.stream.start()
        self._t0 = self._next_frame = self._clock()

    def stop(self) -> None:
        """Stop the boards; wait for recordings being written, and announce them (a client
        waiting for its recording must hear of it even when live mode ends first)."""
        self.stream.stop()
        for thread in self._recorders:
            thread.join()
        self._announce_written()

    def _announce_written(self) -> None:
        """A `live_recorded` event for every recording finished since the last call."""
        while self._written:
            path, error = self._written.pop(0)
            self._publish_event(LiveRecordedEvent, path=str(path), error=error)

    def behind_s(self) -> float:
        """How far the reads trail the clock."""
        return max(0.0, self._clock() - self._t0 - self.stream.index / self.sample_rate_hz)

    def tick(self) -> None:
        """Read what is due, publish it, take the frames that are due. Raises LiveFault."""
        fs = self.sample_rate_hz
        due = int((self._clock() - self._t0) * fs) - self.stream.index
        for _ in range(min(due // BLOCK_SAMPLES, MAX_BLOCKS_PER_TICK)):
            start = self.stream.index
            try:
                codes = self.stream.read(BLOCK_SAMPLES)
            except DaqError as exc:
                raise LiveFault(f"live mode stopped at sample {start}: {exc}") from exc
            self.ring.append(codes)
            if self.options.samples:
                header = SamplesHeader(start=start, n_samples=codes.shape[0],
                                       n_columns=codes.shape[1], sample_rate_hz=fs,
                                       monotonic_s=self._t0 + start / fs)
                self._publish_frames(SAMPLES_TOPIC, [header.model_dump_json().encode(),
                                                     np.ascontiguousarray(codes, "<i2").data])
        self.max_behind_s = max(self.max_behind_s, self.behind_s())
        self._announce_written()
        if self._clock() >= self._next_frame:
            self._next_frame += 1.0 / self.options.camera_fps
            self._next_frame = max(self._next_frame, self._clock())  # no burst after a stall
            for camera in self.cameras:
                self._take_frame(camera)

    def _take_frame(self, camera: Camera) -> None:
        try:
            image = camera.grab(self._timeout_s).image
        except CameraError as exc:
            log.info("no live frame of %s: %s", camera.name, exc)
            return
        sample = self.stream.index
        self.frames.append(StampedFrame(camera.name, sample, image))
        self.n_frames += 1
        jpeg, width, height = encode_preview(image, None, (0, 0), FRAME_WIDTH, FRAME_QUALITY)
        self._publish_event(LiveFrameEvent, camera=camera.name, sample=sample, width=width,
                            height=height, source_width=image.shape[1],
                            source_height=image.shape[0],
                            jpeg_b64=base64.b64encode(jpeg).decode("ascii"))

    def status(self) -> LiveStatus:
        fs = self.sample_rate_hz
        return LiveStatus(sample=self.stream.index, sample_rate_hz=fs,
                          held_s=(self.ring.end - self.ring.start) / fs,
                          capacity_s=self.ring.capacity / fs, behind_s=self.behind_s(),
                          max_behind_s=self.max_behind_s, frames=self.n_frames)

    def record(self, root: Path, seconds: float) -> LiveRecordResult:
        """Store the latest `seconds` of the ring (record.py) in a new directory under `root`,
        on a thread (the loop must keep reading); the next tick after it is written publishes
        a `live_recorded` event (with the error's text if it failed)."""
        fs = self.sample_rate_hz
        first, codes = self.ring.latest(round(seconds * fs))
        if codes.shape[0] == 0:
            raise UserError("live mode has not recorded anything yet; try again in a moment")
        frames = self.frames.between(first, first + codes.shape[0])
        session = f"live-{datetime.now(UTC):%Y-%m-%dT%H-%M-%S.%fZ}"
        path = Path(root) / session

        def write() -> None:
            error = ""
            try:
                write_live_recording(path, self.config, codes, first, frames, session)
            except Exception as exc:  # a full disk: say so, keep live mode running
                log.exception("live recording %s failed", path)
                error = f"{type(exc).__name__}: {exc}"
            self._written.append((path, error))  # published by the loop's thread (tick)

        thread = threading.Thread(target=write, name="micam-live-record", daemon=True)
        self._recorders = [t for t in self._recorders if t.is_alive()] + [thread]
        thread.start()
        return LiveRecordResult(path=str(path), session=session,
                                seconds=codes.shape[0] / fs,
                                acoular_file=str(path / ACOULAR_FILE))
