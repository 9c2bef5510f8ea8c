"""The page's live acoustic view: maps of the daemon's live mode, drawn for the browsers.

`micam web --geometry result.json` makes one `LiveStream`. While the daemon is in live mode
and a browser is connected (the bridge says so, `want`), a thread of the page subscribes to
the daemon's stream like any client (`micam.live_feed.LiveFeed`), draws the maps
over camera 0's frames (`MapFrames`) at `fps`, and hands each frame, as a JPEG, to the bridge,
which sends it to the browsers as the `live_stream` part of the page's state, with the
array's mean spectrum over the map's window and the settings it was drawn with. The imaging runs
in the page's process, never in the daemon's: a slow page only draws fewer frames.

The operator changes the band, its width, the range and the plane while it runs (`retune`,
checked in live_controls.py): the thread makes a new imager (the steering of the new band or
plane) and goes on drawing the same stream with it, without leaving live mode or reconnecting.
"""

from __future__ import annotations

import base64
import logging
import threading
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import cv2

from imaging.geometry import ArrayGeometry
from imaging.live import LiveImager, LiveSettings
from imaging.live_frames import MapFrames, caption_of
from micam.live_feed import FedFrame, LiveFeed

from acquisition.contracts.errors import UserError
from acquisition.daemon.client import DaemonClient, DaemonError
from .live_controls import controls_of, retuned, view_of

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
        self._lock = threading.Lock()  # settings: set by the page's loop, read by the thread
        self._sample_rate_hz: float | None = None  # the stream's, once it was seen

    def controls(self) -> dict[str, Any]:
        """The view's settings as the page's controls show them."""
        with self._lock:
            return controls_of(self.settings)

    def retune(self, args: dict[str, Any]) -> dict[str, Any]:
        """Change band, fraction, range or depth of the running view (LiveViewError if a
        value is refused); the new controls."""
        with self._lock:
            self.settings = retuned(self.settings, args, self._sample_rate_hz)
            return controls_of(self.settings)

    def _imager_for(self, rate: float) -> LiveImager:
        """The imager of the current settings at `rate`: made again only when they changed
        (the steering vectors take 0.4-0.7 s for 48 microphones), and not even then when only
        the range did."""
        with self._lock:
            settings = self.settings
            self._sample_rate_hz = rate
        imager = self._imager
        if imager is None or imager.sample_rate_hz != rate:
            imager = LiveImager(self.geometry, settings, rate)
        elif imager.settings != settings:
            same_set_up = replace(imager.settings, dynamic_range_db=settings.dynamic_range_db)
            imager = (imager.with_range(settings.dynamic_range_db) if same_set_up == settings
                      else LiveImager(self.geometry, settings, rate))
        self._imager = imager
        return imager

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
            except (DaemonError, ValueError, UserError) as exc:
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
            imager = self._imager_for(rate)
            frames = MapFrames(imager, self.fps, caption_of(imager), spectrum=True)
            with LiveFeed(client, frames, self.geometry) as feed:
                while self._wanted.is_set() and not self._closing.is_set():
                    for fed in feed.frames_for(1.0):
                        publish(_page_frame(fed, frames))
                        if not self._wanted.is_set():
                            return
                        imager = self._imager_for(rate)
                        if imager is not frames.imager:  # retuned
                            frames.retune(imager, caption_of(imager))


def _page_frame(fed: FedFrame, frames: MapFrames) -> dict[str, Any]:
    """A drawn frame as the page shows it (with the settings it was drawn with, and the
    spectrum's band levels in dB rounded to 0.1 dB)."""
    image = fed.frame.image
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise ValueError("OpenCV could not encode a live frame as JPEG")
    live_map = fed.frame.live_map
    return {"jpeg_b64": base64.b64encode(jpeg.tobytes()).decode("ascii"),
            "width": int(image.shape[1]), "height": int(image.shape[0]),
            "peak_px": [float(v) for v in live_map.peak_px],
            "latency_ms": round(1e3 * fed.latency_s, 1),
            "components": live_map.n_components, "sample": live_map.end_sample,
            "settings": view_of(fed.frame.settings),
            "spectrum": None if fed.frame.spectrum_db is None or frames.spectrum is None else {
                "centres_hz": [round(float(c), 1) for c in frames.spectrum.centres_hz],
                "levels_db": [round(float(v), 1) for v in fed.frame.spectrum_db]}}
