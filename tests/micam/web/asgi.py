"""Calling the page's ASGI application directly, with any scope a server could hand it (or
none could: no Host, two of them, raw bytes), and a fake bridge in place of the daemon's."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

from starlette.types import ASGIApp, Message

from acquisition.daemon.client import DaemonError
from imaging.live import LiveSettings
from micam.web.bridge import Bridge, Browser
from micam.web.live_stream import LiveStream

PORT = 8765
HOST = f"127.0.0.1:{PORT}"
WAIT_S = 10.0


@dataclass
class Answer:
    """What the application did: an HTTP response (or a WebSocket's HTTP denial), or, for a
    WebSocket, `accepted` / `closed` with a close code."""

    status: int | None = None
    headers: dict[str, str] = field(default_factory=dict)
    body: bytes = b""
    accepted: bool = False
    close_code: int | None = None
    texts: list[str] = field(default_factory=list)

    def json(self) -> Any:
        return json.loads(self.body)


class FakeBridge:
    """The bridge's surface the routes use; `files` answers `session.file` (missing: the
    daemon's refusal), every request is recorded in `requests`."""

    target_m = 5e-4

    def __init__(self, files: dict[str, bytes] | None = None) -> None:
        # a live view never started: `live.view` changes its settings (None: no --geometry)
        self.live_stream: LiveStream | None = LiveStream(
            lambda: None, None, LiveSettings())  # type: ignore[arg-type, return-value]
        self.files = files if files is not None else {}
        self.requests: list[tuple[str, dict[str, Any]]] = []
        self.browsers: set[Browser] = set()

    def as_bridge(self) -> Bridge:
        """This fake where the page takes the daemon's bridge: a stand-in for it."""
        return cast(Bridge, self)

    async def start(self) -> None:
        pass

    async def stop(self) -> None:
        pass

    def snapshot(self) -> dict[str, Any]:
        return {"daemon": {"connected": True}, "status": None}

    def retune_live(self, args: dict[str, Any]) -> dict[str, Any]:
        assert self.live_stream is not None
        return self.live_stream.retune(args)

    connect = Bridge.connect  # the real fan-out: the browsers and their queues
    disconnect = Bridge.disconnect

    async def request(self, command: str, **args: Any) -> dict[str, Any]:
        self.requests.append((command, args))
        if command == "session.report":
            return {"session": {"id": args["session"]}, "steps": [],
                    "files": [{"path": p, "bytes": len(b)} for p, b in self.files.items()]}
        if command == "capture":
            raise DaemonError("not waiting for a capture", code="bad_state")
        return {"done": command}

    async def file(self, session_id: str, path: str) -> bytes:
        if path not in self.files:
            raise DaemonError(f"{path}: cannot open it", code="session_error")
        return self.files[path]


def scope_of(method: str, path: str, headers: list[tuple[bytes, bytes]],
             query: bytes = b"", kind: str = "http", denial: bool = True) -> dict[str, Any]:
    scope: dict[str, Any] = {
        "type": kind, "asgi": {"version": "3.0", "spec_version": "2.3"},
        "http_version": "1.1", "scheme": "http" if kind == "http" else "ws", "path": path,
        "raw_path": path.encode("utf-8", "surrogateescape"), "query_string": query,
        "root_path": "", "headers": headers, "server": ("127.0.0.1", PORT),
        "client": ("127.0.0.1", 40000), "state": {}}
    if kind == "http":
        scope["method"] = method
    elif denial:
        scope["extensions"] = {"websocket.http.response": {}}
    return scope


async def call(app: ASGIApp, scope: dict[str, Any], chunks: list[bytes] | None = None
               ) -> Answer:
    """Run one request (the body in `chunks`) or one WebSocket (connect, then leave once
    accepted) through `app`."""
    answer = Answer()
    done = asyncio.Event()
    pending = list(chunks if chunks is not None else [b""])
    connected = False

    async def receive() -> Message:
        nonlocal connected
        if scope["type"] == "websocket":
            if not connected:
                connected = True
                return {"type": "websocket.connect"}
            await done.wait()
            return {"type": "websocket.disconnect", "code": 1000}
        if pending:
            body = pending.pop(0)
            return {"type": "http.request", "body": body, "more_body": bool(pending)}
        await done.wait()
        return {"type": "http.disconnect"}

    async def send(message: Message) -> None:
        kind = message["type"].removeprefix("websocket.")
        if kind == "http.response.start":
            answer.status = message["status"]
            answer.headers = {k.decode("latin-1"): v.decode("latin-1")
                              for k, v in message.get("headers", [])}
        elif kind == "http.response.body":
            answer.body += message.get("body", b"")
            if not message.get("more_body", False):
                done.set()
        elif kind == "accept":
            answer.accepted = True
        elif kind == "send":
            answer.texts.append(message.get("text") or "")
            done.set()  # the snapshot came: leave
        elif kind == "close":
            answer.close_code = message.get("code", 1000)
            done.set()

    await asyncio.wait_for(app(scope, receive, send), WAIT_S)
    return answer


def runner() -> tuple[Callable[..., Answer], Callable[[], None]]:
    """`run(app, scope, chunks)` on one event loop kept for many calls, and its closer."""
    loop = asyncio.new_event_loop()

    def run(app: ASGIApp, scope: dict[str, Any], chunks: list[bytes] | None = None) -> Answer:
        return loop.run_until_complete(call(app, scope, chunks))

    return run, loop.close
