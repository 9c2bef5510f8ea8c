"""The page's live acoustic view: maps of the daemon's live mode, drawn for the browsers.

`micam web --geometry result.json` makes one `LiveStream`. While the daemon is in live mode
and a browser is connected (the bridge says so, `want`), a thread of the page subscribes to
the daemon's stream like any client (`micam.live_feed.LiveFeed`), draws the maps
over camera 0's frames (`MapFrames`) at `fps`, and hands each frame, as a JPEG, to the bridge,
which sends it to the browsers as the `live_stream` part of the page's state. The imaging runs
in the page's process, never in the daemon's: a slow page only draws fewer frames.
"""

from __future__ import annotations

import base64
import logging
import threading
from collections.abc import Callable
from typing import Any

import cv2

from calibration.imaging.geometry import ArrayGeometry
from calibration.imaging.live import LiveImager, LiveSettings
from micam.live_feed import FedFrame, LiveFeed
from calibration.imaging.live_frames import MapFrames, caption_of

from acquisition.daemon.client import DaemonClient, DaemonError

log = logging.getLogger("micam.web")

JPEG_QUALITY = 80
RETRY_S = 1.0


class LiveStream:
    """See the module docstring.

    Args:
        make_client: a new client of the daemon (the thread's own).
        geometry: the calibration the maps are computed with.
        settings: band, plane, method, range.
        fps: frames per second drawn for the page.
    """

    def __init__(self, make_client: Callable[[], DaemonClient], geometry: ArrayGeometry,
                 settings: LiveSettings, fps: float = 10.0) -> None:
        self.make_client = make_client
        self.geometry = geometry
        self.settings = settings
        self.fps = fps
        self._wanted = threading.Event()
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._imager: LiveImager | None = None

    def start(self, publish: Callable[[dict[str, Any]], None]) -> None:
        """Run the thread; `publish(frame)` is called from it for every frame drawn (it must
        hand the frame over to the page's loop itself)."""
        self._thread = threading.Thread(target=self._run, args=(publish,),
                                        name="micam-live-stream", daemon=True)
        self._thread.start()

    def want(self, on: bool) -> None:
        """Draw frames (the daemon is live and a browser looks) or not."""
        if on:
            self._wanted.set()
        else:
            self._wanted.clear()

    def close(self) -> None:
        self._closing.set()
        self._wanted.set()
        if self._thread is not None:
            self._thread.join(10.0)

    def _run(self, publish: Callable[[dict[str, Any]], None]) -> None:
        while not self._closing.is_set():
            self._wanted.wait()
            if self._closing.is_set():
                return
            try:
                self._stream(publish)
            except (DaemonError, ValueError) as exc:
                log.warning("live view: %s", exc)
                publish({"error": str(exc)})
                self._closing.wait(RETRY_S)

    def _stream(self, publish: Callable[[dict[str, Any]], None]) -> None:
        with self.make_client() as client:
            status = client.status()
            if status.live is None:
                self._closing.wait(RETRY_S)
                return
            rate = status.live.sample_rate_hz
            if self._imager is None or self._imager.sample_rate_hz != rate:
                self._imager = LiveImager(self.geometry, self.settings, rate)  # steering once
            frames = MapFrames(self._imager, self.fps, caption_of(self._imager))
            with LiveFeed(client, frames, self.geometry) as feed:
                while self._wanted.is_set() and not self._closing.is_set():
                    for fed in feed.frames_for(1.0):
                        publish(_page_frame(fed))
                        if not self._wanted.is_set():
                            return


def _page_frame(fed: FedFrame) -> dict[str, Any]:
    """A drawn frame as the page shows it."""
    image = fed.frame.image
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("OpenCV could not encode a live frame as JPEG")
    live_map = fed.frame.live_map
    return {"jpeg_b64": base64.b64encode(jpeg.tobytes()).decode("ascii"),
            "width": int(image.shape[1]), "height": int(image.shape[0]),
            "peak_px": [float(v) for v in live_map.peak_px],
            "latency_ms": round(1e3 * fed.latency_s, 1),
            "components": live_map.n_components, "sample": live_map.end_sample}
