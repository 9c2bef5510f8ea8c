"""Live mode's stream from the daemon, as a client of its protocol (docs/protocol.md).

`LiveFeed` subscribes to the daemon's `samples` messages (the time data) and `live_frame`
events (camera frames), validates every message (a header that does not parse, a payload of
the wrong size, a frame that does not decode are dropped and counted, never trusted), picks
the microphone columns in the geometry's order and converts them to volts with the ranges
`describe` states, and feeds a `MapFrames`. Each drawn frame comes with its latency: the time
from the scan of the newest sample in the map's window (the daemon's monotonic clock, the same
clock on the same host) to the frame being drawn.
"""

from __future__ import annotations

import base64
import json
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np
import zmq
from pydantic import ValidationError

from acquisition.contracts.errors import UserError
from acquisition.contracts.protocol import (
    EVENT_ADAPTER,
    LIVE_FRAME_TOPIC,
    SAMPLES_TOPIC,
    DescribeResult,
    LiveFrameEvent,
    SamplesHeader,
)
from acquisition.daemon.client import DaemonClient

from imaging.geometry import ArrayGeometry
from imaging.live_frames import DrawnFrame, MapFrames


@dataclass(frozen=True)
class FedFrame:
    """A drawn frame and its latency (seconds from the scan of its newest sample)."""

    frame: DrawnFrame
    latency_s: float


class _Column(Protocol):
    @property
    def role(self) -> str: ...
    @property
    def mic_id(self) -> int | None: ...
    @property
    def range_v(self) -> float | None: ...


def mic_columns(columns: Sequence[_Column], geometry: ArrayGeometry
                ) -> tuple[np.ndarray, np.ndarray]:
    """The positions (M,) of the geometry's microphones among `columns` (a capture
    configuration's, or `describe`'s) and their volts per code (M,). Raises UserError naming
    a microphone that is not recorded."""
    by_id = {c.mic_id: (j, c.range_v) for j, c in enumerate(columns) if c.role == "mic"}
    missing = [m for m in geometry.mic_ids if m not in by_id]
    if missing:
        raise UserError(f"no microphone {missing[:5]} of the geometry is recorded; use the "
                        "calibration of this array")
    index = np.array([by_id[m][0] for m in geometry.mic_ids])
    scale = np.array([(by_id[m][1] or 1.0) / 32768.0 for m in geometry.mic_ids])
    return index, scale


class LiveFeed:
    """Frames drawn from a daemon's live mode (module docstring).

    Args:
        client: the daemon.
        frames: draws the maps (its imager's camera is the camera whose frames are used).
        geometry: the calibration whose microphones are imaged.
    """

    def __init__(self, client: DaemonClient, frames: MapFrames, geometry: ArrayGeometry) -> None:
        self.frames = frames
        describe = DescribeResult.model_validate(client.request("describe"))
        self.columns, self.scale = mic_columns(describe.columns, geometry)
        self.n_columns = len(describe.columns)
        self.camera = frames.imager.settings.camera
        self.dropped = 0
        self._socket = client.topic_socket((SAMPLES_TOPIC, LIVE_FRAME_TOPIC))
        self._t0: float | None = None  # the daemon's clock at stream index 0

    def close(self) -> None:
        self._socket.close(linger=0)

    def __enter__(self) -> LiveFeed:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def frames_for(self, seconds: float) -> Iterator[FedFrame]:
        """Drawn frames for `seconds` of wall-clock time (or until nothing arrives for that
        long)."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            if not self._socket.poll(round(left * 1000), zmq.POLLIN):
                return
            yield from self._receive(self._socket.recv_multipart())

    def _receive(self, message: list[bytes]) -> list[FedFrame]:
        topic = message[0].decode(errors="replace")
        if topic == SAMPLES_TOPIC:
            return self._samples(message)
        if topic == LIVE_FRAME_TOPIC and len(message) == 2:
            self._frame(message[1])
        return []

    def _samples(self, message: list[bytes]) -> list[FedFrame]:
        try:
            if len(message) != 3:
                raise ValueError("a samples message has three frames")
            header = SamplesHeader.model_validate(json.loads(message[1]))
            if header.n_columns != self.n_columns or len(message[2]) != (
                    2 * header.n_samples * header.n_columns):
                raise ValueError("the payload does not match its header")
        except (ValueError, ValidationError):
            self.dropped += 1
            return []
        self._t0 = header.monotonic_s - header.start / header.sample_rate_hz
        codes = np.frombuffer(message[2], dtype="<i2").reshape(header.n_samples, -1)
        volts = codes[:, self.columns] * self.scale
        drawn = self.frames.push(header.start, volts)
        now = time.monotonic()
        return [FedFrame(f, now - (self._t0 + f.live_map.end_sample / header.sample_rate_hz))
                for f in drawn]

    def _frame(self, payload: bytes) -> None:
        try:
            event = EVENT_ADAPTER.validate_json(payload)
            if not isinstance(event, LiveFrameEvent) or event.camera != self.camera:
                return
            jpeg = np.frombuffer(base64.b64decode(event.jpeg_b64, validate=True), np.uint8)
            image = cv2.imdecode(jpeg, cv2.IMREAD_UNCHANGED)
            if image is None:
                raise ValueError("not a JPEG")
        except (ValueError, ValidationError):
            self.dropped += 1
            return
        self.frames.add_frame(event.sample, image)
