"""The operator's page as a Starlette application (served by uvicorn in `micam web`).

Routes: `/` the page, `/static/...` its script and style, `/ws` the live updates (a snapshot,
then one update per daemon event), `POST /api/command` the controls, `/api/state` the
snapshot (for scripts and tests), `/api/sessions/{id}/report` a session's report and
`/api/sessions/{id}/files/{path}` its calibration files (result, figures). Every request
passes `AccessGuard` (access.py) first.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect

from acquisition.daemon.client import DaemonError
from acquisition.contracts.safe_names import is_name, is_relative_path
from .access import COOKIE, same_origin, token_matches
from .bridge import Bridge, Browser
from .view import live_view, result_view

STATIC = Path(__file__).with_name("static")
MAX_COMMAND_BYTES = 4096
COMMANDS: dict[str, frozenset[str]] = {
    "session.start": frozenset({"poses", "resume"}),
    "capture": frozenset(), "redo": frozenset(), "session.pause": frozenset(),
    "session.resume": frozenset(), "session.stop": frozenset(), "session.abort": frozenset(),
    "live.start": frozenset({"seconds", "camera_fps", "cameras"}), "live.stop": frozenset(),
    "live.record": frozenset({"seconds"}),
}
"""What the page may ask the daemon to do, with the arguments of each."""
MEDIA_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".json": "application/json",
               ".jsonl": "text/plain; charset=utf-8", ".md": "text/plain; charset=utf-8",
               ".txt": "text/plain; charset=utf-8", ".xml": "text/plain; charset=utf-8"}
"""The calibration files the page serves, as what (no HTML, no SVG: nothing that runs)."""
SECURITY_HEADERS = [
    (b"content-security-policy", b"default-src 'self'; img-src 'self' data:; "
                                 b"connect-src 'self'; frame-ancestors 'none'"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"cache-control", b"no-store"),
]


class AccessGuard:
    """ASGI middleware: the token (cookie, bearer header, or `?token=` on the page's address),
    the same-origin rule for POST and the WebSocket, and the security headers."""

    def __init__(self, app: ASGIApp, token: str | None) -> None:
        self.app = app
        self.token = token

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope["headers"]}
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        given = query.get("token", [None])[0]
        if not same_origin(headers.get("origin"), headers.get("host")) and (
                scope["type"] == "websocket" or scope["method"] != "GET"):
            await self._refuse(scope, receive, send, 403, "refused: the request comes from "
                                                          "another site than this page")
            return
        if given is not None and scope["type"] == "http" and scope["path"] == "/":
            if token_matches(self.token, given):  # the address with the token: set the cookie
                await Response(status_code=303, headers={
                    "location": "/", "set-cookie": f"{COOKIE}={given}; HttpOnly; "
                                                   "SameSite=Strict; Path=/"})(scope, receive,
                                                                               send)
                return
        presented = _cookie(headers.get("cookie", ""), COOKIE) or _bearer(
            headers.get("authorization", "")) or given
        if not token_matches(self.token, presented):
            await self._refuse(scope, receive, send, 401, "this page needs its token: open it "
                                                          "as /?token=TOKEN (docs/operator.md)")
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []),
                                                  *SECURITY_HEADERS]}
            await send(message)

        await self.app(scope, receive, send_with_headers)

    @staticmethod
    async def _refuse(scope: Scope, receive: Receive, send: Send, status: int,
                      text: str) -> None:
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 4000 + status, "reason": text})
            return
        await PlainTextResponse(text, status_code=status)(scope, receive, send)


def _cookie(header: str, name: str) -> str | None:
    for part in header.split(";"):
        key, _, value = part.strip().partition("=")
        if key == name:
            return value
    return None


def _bearer(header: str) -> str | None:
    scheme, _, value = header.partition(" ")
    return value.strip() if scheme.lower() == "bearer" and value else None


def create_app(bridge: Bridge, token: str | None) -> Starlette:
    """The page's application around `bridge` (started and stopped with the application)."""

    @contextlib.asynccontextmanager
    async def lifespan(_app: Starlette) -> AsyncIterator[None]:
        await bridge.start()
        try:
            yield
        finally:
            await bridge.stop()

    async def index(_request: Request) -> Response:
        return FileResponse(STATIC / "index.html")

    async def state(_request: Request) -> Response:
        return JSONResponse(bridge.snapshot())

    async def command(request: Request) -> Response:
        body = await request.body()
        if len(body) > MAX_COMMAND_BYTES:
            return _error(413, "bad_request", "the command is too long")
        try:
            data = json.loads(body)
            name, args = data["command"], data.get("args") or {}
            allowed = COMMANDS[name]
            if not isinstance(args, dict) or set(args) - allowed:
                raise KeyError(name)
        except (ValueError, KeyError, TypeError):
            return _error(400, "bad_request", "send {\"command\": NAME, \"args\": {...}} with "
                                              f"NAME one of {', '.join(COMMANDS)}")
        if name == "session.abort" and data.get("confirm") is not True:
            return _error(400, "bad_request", "aborting ends the session for good: send "
                                              "\"confirm\": true")
        try:
            result = await bridge.request(name, **{k: v for k, v in args.items()
                                                   if v not in (None, "")})
        except DaemonError as exc:
            return _error(409 if exc.code else 503, exc.code or "unreachable", str(exc))
        return JSONResponse({"ok": True, "result": result})

    async def report(request: Request) -> Response:
        session = request.path_params["session"]
        if not is_name(session):
            return _error(400, "bad_request", "not a session id")
        try:
            reply = await bridge.request("session.report", session=session)
        except DaemonError as exc:
            return _error(404 if exc.code else 503, exc.code or "unreachable", str(exc))
        paths = {f["path"] for f in reply["files"]}
        extra: dict[str, Any] = {}
        for path, key, make in (("calibration/result.json", "result", result_view),
                                ("calibration/live.json", "live",
                                 lambda u: live_view(u, bridge.target_m))):
            if path in paths:
                with contextlib.suppress(DaemonError, ValueError, KeyError, TypeError):
                    extra[key] = make(json.loads(await bridge.file(session, path)))
        return JSONResponse({**reply, **extra})

    async def file(request: Request) -> Response:
        session, path = request.path_params["session"], request.path_params["path"]
        media = MEDIA_TYPES.get(Path(path).suffix.lower())
        if not (is_name(session) and is_relative_path(path)) or media is None:
            return _error(400, "bad_request", "not a calibration file this page shows")
        try:
            data = await bridge.file(session, path)
        except DaemonError as exc:
            return _error(404 if exc.code else 503, exc.code or "unreachable", str(exc))
        return Response(data, media_type=media)

    async def websocket(ws: WebSocket) -> None:
        await ws.accept()
        browser, snapshot = bridge.connect()
        try:
            await ws.send_text(snapshot)
            closed = asyncio.create_task(_until_closed(ws, browser))
            while (text := await browser.queue.get()) is not None:
                await ws.send_text(text)
            closed.cancel()
            with contextlib.suppress(Exception):
                await ws.close()
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            bridge.disconnect(browser)

    routes = [
        Route("/", index), Route("/api/state", state),
        Route("/api/command", command, methods=["POST"]),
        Route("/api/sessions/{session}/report", report),
        Route("/api/sessions/{session}/files/{path:path}", file),
        WebSocketRoute("/ws", websocket),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    app = Starlette(routes=routes, lifespan=lifespan)
    app.add_middleware(AccessGuard, token=token)
    return app


async def _until_closed(ws: WebSocket, browser: Browser) -> None:
    """Read (and ignore) what the page sends until it goes; then end its queue."""
    with contextlib.suppress(Exception):
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
    browser.end()


def _error(status: int, code: str, message: str) -> JSONResponse:
    return JSONResponse({"ok": False, "code": code, "error": message}, status_code=status)
