"""The page's one connection to the daemon, and the fan-out of its events to the browsers.

The bridge subscribes to every event (previews included), polls `status` every `poll_s`
seconds (events may be missed, status replies are not), asks for previews while a browser is
connected, and keeps the page's state: what the daemon is doing, what it captures with, the
latest levels and previews, the live calibration and its history, the sessions. Each browser
gets a snapshot of that state when it connects, then one update per event, in order.

What belongs to a session (its levels, board views per camera, progress, live calibration and
history) is kept in one place, `SESSION_STATE`'s keys, for the open session only: it starts
again from `SESSION_STATE` whenever the open session changes (a new one, or none after stop or
abort), so that nothing of one session shows in the next, and a page that connects later gets
it whole in its snapshot. Events of another session than the open one (a worker's late live
calibration of a closed session) do not touch it.

It picks up where the daemon is whenever it (re)connects: a restarted page reads the daemon's
status, its description and the open session's live calibration files, and a restarted daemon
(its event numbers start again at 0) is read afresh the same way. A browser that cannot keep
up (its queue is full) is dropped; its page reconnects and gets a new snapshot.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
import time
from collections import deque
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, cast

import zmq
import zmq.asyncio
from pydantic import ValidationError

from acquisition.daemon.client import DaemonClient, DaemonError
from micam.display import format_event
from acquisition.contracts.protocol import (
    EVENT_ADAPTER,
    CalibrationEvent,
    DescribeResult,
    Event,
    LevelsEvent,
    LiveCalibrationEvent,
    LiveFrameEvent,
    PreviewEvent,
    ProgressEvent,
    StateEvent,
    StatusResult,
)
from .json_body import JsonInputError, load_json
from .view import ViewError, cameras_view, history_point, levels_view, live_view

if TYPE_CHECKING:
    from .live_stream import LiveStream

log = logging.getLogger("micam.web")

LOG_LINES = 100
QUEUE_LENGTH = 256
"""Updates queued per browser: beyond them the browser is too slow and is dropped."""
PREVIEW_LEASE_S = 6.0
HISTORY_LIMIT = 10_000
LIVE_FILE = "calibration/live.json"
LIVE_HISTORY_FILE = "calibration/live_history.jsonl"
MAX_FILE_BYTES = 4 * 2**20
"""The longest session file the page reads (the daemon sends at most as much)."""
SESSION_STATE: dict[str, Any] = {"cameras": [], "levels": None, "progress": None, "live": None,
                                 "live_history": []}
"""The page's state of the open session, as it is when a session opens (or none is open)."""
CLOSED_REMEMBERED = 100
"""Closed sessions remembered, whose late events never reopen them on the page."""


class Browser:
    """One connected page: a bounded queue of updates as JSON text (None: the end)."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue[str | None] = asyncio.Queue(QUEUE_LENGTH)

    def offer(self, update: str) -> bool:
        """Queue `update`; False (and the end) if the queue is full."""
        try:
            self.queue.put_nowait(update)
        except asyncio.QueueFull:
            self.end()
            return False
        return True

    def end(self) -> None:
        """Make the page's loop end after what it has (dropping one update to make room)."""
        if self.queue.full():
            with contextlib.suppress(asyncio.QueueEmpty):
                self.queue.get_nowait()
        self.queue.put_nowait(None)


class Bridge:
    """See the module docstring. `client` makes the requests; `target_m` is the accuracy at
    which the page says "enough poses"."""

    def __init__(self, client: DaemonClient, target_m: float | None = None,
                 poll_s: float = 1.0, sessions_every_s: float = 10.0,
                 live_stream: LiveStream | None = None) -> None:
        self.client = client
        self.live_stream = live_stream
        self.target_m = target_m
        self.poll_s = poll_s
        self.sessions_every_s = sessions_every_s
        self.browsers: set[Browser] = set()
        self.state: dict[str, Any] = {
            "daemon": {"connected": False, "error": "connecting to the daemon",
                       "control": client.control},
            "describe": None, "status": None, "previews": {}, "sessions": None, "log": [],
            "target_m": target_m, "live_stream": None, "session_id": None, **SESSION_STATE,
            "live_view": live_stream.controls() if live_stream is not None else None,
        }
        self._log: deque[dict[str, Any]] = deque(maxlen=LOG_LINES)
        self._describe: DescribeResult | None = None
        self._last_seq: int | None = None
        self._closed: deque[str] = deque(maxlen=CLOSED_REMEMBERED)
        self._live_unread = False  # the open session's live files are still to be read
        self._tasks: list[asyncio.Task] = []
        self._context = zmq.asyncio.Context()
        self._resync = asyncio.Event()

    # -- life --------------------------------------------------------------------------------

    async def start(self) -> None:
        self._tasks = [asyncio.create_task(self._events(), name="daemon events"),
                       asyncio.create_task(self._poll(), name="daemon status")]
        if self.live_stream is not None:
            loop = asyncio.get_running_loop()

            def publish(frame: dict[str, Any]) -> None:  # from the live view's thread
                loop.call_soon_threadsafe(self._send, {"live_stream": frame})

            self.live_stream.start(publish)

    async def stop(self) -> None:
        if self.live_stream is not None:
            await asyncio.to_thread(self.live_stream.close)
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for browser in list(self.browsers):
            browser.end()
        self._context.destroy(linger=0)

    def connect(self) -> tuple[Browser, str]:
        """A new browser and the snapshot it starts from (JSON text)."""
        browser = Browser()
        self.browsers.add(browser)
        return browser, json.dumps({"kind": "snapshot", "state": self.snapshot()})

    def disconnect(self, browser: Browser) -> None:
        self.browsers.discard(browser)

    def snapshot(self) -> dict[str, Any]:
        return {**self.state, "log": list(self._log)}

    async def request(self, command: str, **args: Any) -> dict[str, Any]:
        """One request to the daemon (DaemonError with its refusal, or if it is unreachable)."""
        return await asyncio.to_thread(self.client.request, command, **args)

    def retune_live(self, args: dict[str, Any]) -> dict[str, Any]:
        """Change the live view (band, fraction, range, depth) while it runs, and show every
        page the new controls; live_controls.LiveViewError if a value is refused."""
        assert self.live_stream is not None, "the page asks for a live view only with one"
        controls = self.live_stream.retune(args)
        self._send({"live_view": controls})
        return controls

    # -- fan-out -----------------------------------------------------------------------------

    def _send(self, changed: dict[str, Any], event: dict[str, Any] | None = None) -> None:
        self.state.update(changed)
        update = json.dumps({"kind": "update", "state": changed, "event": event})
        for browser in list(self.browsers):
            if not browser.offer(update):
                log.warning("a browser could not keep up; dropped it (it will reconnect)")
                self.browsers.discard(browser)

    # -- the daemon's events -----------------------------------------------------------------

    async def _events(self) -> None:
        """Receive every event for ever; reconnect after the daemon could not be reached."""
        while True:
            try:
                sock = cast(zmq.asyncio.Socket, await asyncio.to_thread(
                    self.client.event_socket, True, self._context))
            except DaemonError as exc:
                self._disconnected(str(exc))
                await asyncio.sleep(self.poll_s)
                continue
            try:
                while True:
                    _topic, payload = await sock.recv_multipart()
                    self._on_event(payload)
            finally:
                sock.close(linger=0)

    def _on_event(self, payload: bytes) -> None:
        try:
            event = EVENT_ADAPTER.validate_json(payload)
        except ValidationError as exc:
            log.warning("ignored an event this page cannot read: %s", exc.errors()[0]["msg"])
            return
        if self._last_seq is not None and event.seq <= self._last_seq:
            self._resync.set()  # numbers start again: the daemon was restarted
            self._live_unread = True
        self._last_seq = event.seq
        changed = self._apply(event)
        summary = {"seq": event.seq, "type": event.type,
                   "time_utc": event.time_utc.isoformat()}
        if not isinstance(event, PreviewEvent | LiveFrameEvent):
            line = {"seq": event.seq, "time_utc": summary["time_utc"],
                    "line": format_event(event)}
            self._log.append(line)
            summary["line"] = line["line"]
        self._send(changed, summary)

    def _apply(self, event: Event) -> dict[str, Any]:
        """The parts of the page's state that `event` changes (nothing of the open session's
        for an event of another)."""
        if isinstance(event, StateEvent | CalibrationEvent):
            self._resync.set()  # a session opened or closed, a result arrived: read again
        if isinstance(event, PreviewEvent):
            return {"previews": {**self.state["previews"], event.camera: event.model_dump(
                mode="json", exclude={"v", "seq", "time_utc", "session_id", "type"})}}
        changed: dict[str, Any] = {}
        if (isinstance(event, LevelsEvent | ProgressEvent) and event.session_id is not None
                and event.session_id != self.state["session_id"]
                and event.session_id not in self._closed):
            changed = self._open(event.session_id)  # the capture's events come before status
            self.state.update(changed)
        if event.session_id is None or event.session_id != self.state["session_id"]:
            return changed  # another session's (a worker's late reply), or none
        if isinstance(event, LevelsEvent) and self._describe is not None:
            return {**changed, "levels": levels_view(event, self._describe)}
        if isinstance(event, ProgressEvent):
            status = self.state["status"]
            changed["progress"] = event.model_dump(mode="json")
            if self._describe is not None:
                changed["cameras"] = cameras_view(self._describe, event.cameras,
                                                  event.poses_done, event.n_poses)
            if status is not None and event.outline is not None:
                changed["status"] = {**status, "coverage": [*status.get("coverage", []),
                                                            event.outline.model_dump()]}
            return changed
        if isinstance(event, LiveCalibrationEvent):
            try:
                live, point = live_view(event.update, self.target_m), history_point(event.update)
            except ViewError as exc:
                log.warning("ignored a live calibration: %s", exc)
                return {}
            history = [p for p in self.state["live_history"] if p["poses"] != point["poses"]]
            return {"live": live, "live_history": [*history, point][-HISTORY_LIMIT:]}
        return {}

    def _disconnected(self, why: str) -> None:
        if self.state["daemon"]["connected"] or self.state["daemon"]["error"] != why:
            self._send({"daemon": {"connected": False, "error": why,
                                   "control": self.client.control}})

    # -- status polls and resyncs ------------------------------------------------------------

    async def _poll(self) -> None:
        """Poll status; read everything again after a (re)connection or when events say so;
        keep previews coming while a browser is connected."""
        connected = False
        next_sessions = next_lease = 0.0
        while True:
            try:
                if not connected or self._resync.is_set():
                    self._resync.clear()
                    self._live_unread |= not connected
                    await self._read_all()
                    connected = True
                    next_sessions = time.monotonic() + self.sessions_every_s
                status = await asyncio.to_thread(self.client.status)
                await self._on_status(status)
                now = time.monotonic()
                if self.browsers and now >= next_lease:
                    await self.request("previews", seconds=PREVIEW_LEASE_S)
                    next_lease = now + PREVIEW_LEASE_S / 2
                if now >= next_sessions:
                    self._send({"sessions": await self.request("sessions.list")})
                    next_sessions = now + self.sessions_every_s
            except DaemonError as exc:
                connected = False
                next_lease = 0.0
                self._disconnected(str(exc))
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._resync.wait(), self.poll_s)

    async def _read_all(self) -> None:
        """Everything the page shows, read from the daemon afresh."""
        self._describe = DescribeResult.model_validate(await self.request("describe"))
        self._send({"describe": self._describe.model_dump(mode="json"),
                    "daemon": {"connected": True, "error": None, "control": self.client.control},
                    "sessions": await self.request("sessions.list")})
        await self._on_status(await asyncio.to_thread(self.client.status))

    async def _on_status(self, status: StatusResult) -> None:
        if self.live_stream is not None:  # maps only while live and looked at
            self.live_stream.want(bool(self.browsers) and status.live is not None)
        session = status.session
        if (session.id if session else None) != self.state["session_id"]:
            self._send(self._open(session.id if session else None))
        changed: dict[str, Any] = {"status": status.model_dump(mode="json")}
        if status.live is None and self.state["live_stream"] is not None:
            changed["live_stream"] = None  # left live: no last map stays on the page
        if session is not None and self._describe is not None:
            changed["cameras"] = cameras_view(self._describe, status.cameras,
                                              session.poses_done, session.n_poses)
        if session is not None and self._live_unread:
            self._live_unread = False
            changed.update(await self._live_files(session.id))
        if changed != {k: self.state.get(k) for k in changed}:
            self._send(changed)

    def _open(self, session_id: str | None) -> dict[str, Any]:
        """The page's state of a session that opens (or of none), from nothing; the session
        that was open is remembered as closed, its live files to be read if it is resumed."""
        closing = self.state["session_id"]
        if closing is not None and closing != session_id:
            self._closed.append(closing)
        if session_id is not None:
            with contextlib.suppress(ValueError):
                self._closed.remove(session_id)  # resumed: it is open again
            self._live_unread = True
        return {**SESSION_STATE, "session_id": session_id}

    async def _live_files(self, session_id: str) -> dict[str, Any]:
        """The open session's latest live update and its history, from its files (what
        cannot be read or shown is left out, and logged)."""
        live, history = None, []
        with contextlib.suppress(DaemonError):
            try:
                live = live_view(load_json(await self.file(session_id, LIVE_FILE),
                                           MAX_FILE_BYTES, LIVE_FILE), self.target_m)
            except (JsonInputError, ViewError) as exc:
                log.warning("%s: %s", session_id, exc)
        with contextlib.suppress(DaemonError):
            lines = (await self.file(session_id, LIVE_HISTORY_FILE)).splitlines()
            history = _dedup(list(_history_points(session_id, lines)))
        return {"live": live, "live_history": history[-HISTORY_LIMIT:]}

    async def file(self, session_id: str, path: str) -> bytes:
        """A file of a session's calibration directory (DaemonError if it cannot be had)."""
        reply = await self.request("session.file", session=session_id, path=path)
        return base64.b64decode(reply["content_b64"])


def _history_points(session_id: str, lines: list[bytes]) -> Iterator[dict[str, Any]]:
    """The points of a live history file's lines; a line that cannot be read or shown is
    skipped (and logged)."""
    for n, line in enumerate(lines, 1):
        if line.strip():
            try:
                yield history_point(load_json(line, MAX_FILE_BYTES, f"line {n}"))
            except (JsonInputError, ViewError) as exc:
                log.warning("%s, %s: %s", session_id, LIVE_HISTORY_FILE, exc)


def _dedup(points: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The last point of each pose count (a job run again writes its line again), in order."""
    last: dict[Any, dict[str, Any]] = {}
    for p in points:
        last.pop(p["poses"], None)
        last[p["poses"]] = p
    return list(last.values())
