"""The operator's page as a Starlette application (served by uvicorn in `micam web`).

Routes: `/` the page, `/static/...` its script and style, `/ws` the live updates (a snapshot,
then one update per daemon event), `POST /api/command` the controls, `/api/state` the
snapshot (for scripts and tests), `/api/sessions/{id}/report` a session's report and
`/api/sessions/{id}/files/{path}` its calibration files (result, figures). One command is the
page's own, not the daemon's: `live.view` changes the live acoustic view (live_controls.py).
Every request
passes `AccessGuard` (guard.py: Host, Origin, token) and then `BodyLimit` (limits.py: the
body's size and time) first; every refusal says why (refusals.py), none is a 500.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from acquisition.daemon.client import DaemonError
from acquisition.contracts.safe_names import is_name, is_relative_path
from .bridge import MAX_FILE_BYTES, Bridge, Browser
from .guard import WEBSOCKET_PATH, AccessGuard
from .hosts import ServedHosts
from .json_body import JsonInputError, load_json
from .limits import BodyLimit
from .live_controls import ARGUMENTS as LIVE_VIEW_ARGUMENTS, LiveViewError
from .refusals import refusal, shown
from .view import ViewError, live_view, result_view

STATIC = Path(__file__).with_name("static")
MAX_BODY_BYTES = 4096
"""The longest request body the page takes (a command is a few hundred bytes): limits.py."""
COMMANDS: dict[str, frozenset[str]] = {
    "session.start": frozenset({"poses", "resume"}),
    "capture": frozenset(), "redo": frozenset(), "session.pause": frozenset(),
    "session.resume": frozenset(), "session.stop": frozenset(), "session.abort": frozenset(),
    "live.start": frozenset({"seconds", "camera_fps", "cameras"}), "live.stop": frozenset(),
    "live.record": frozenset({"seconds"}), "live.view": LIVE_VIEW_ARGUMENTS,
}
"""What the page may ask the daemon (or, `live.view`, itself) to do, with the arguments of
each."""
MEDIA_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".json": "application/json",
               ".jsonl": "text/plain; charset=utf-8", ".md": "text/plain; charset=utf-8",
               ".txt": "text/plain; charset=utf-8", ".xml": "text/plain; charset=utf-8"}
"""The calibration files the page serves, as what (no HTML, no SVG: nothing that runs)."""
ROUTES = ("/, /api/state, /api/command (POST), /api/sessions/ID/report, "
          "/api/sessions/ID/files/PATH, /ws")


def create_app(bridge: Bridge, token: str | None, served: ServedHosts,
               request_timeout_s: float) -> Starlette:
    """The page's application around `bridge` (started and stopped with the application),
    answering to the names `served`, with the page's `token` (None: none), taking a request
    body within `request_timeout_s` seconds."""

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
        if request.headers.get("content-type", "").partition(";")[0].strip().lower() != (
                "application/json"):
            return refusal(415, "bad_request", "send the command as Content-Type: "
                                               "application/json")
        try:
            name, args = parse_command(await request.body())
        except JsonInputError as exc:
            return refusal(400, "bad_request", str(exc))
        if name == "live.view":
            return _retune_live(bridge, args)
        try:
            result = await bridge.request(name, **args)
        except DaemonError as exc:
            return refusal(409 if exc.code else 503, exc.code or "unreachable", str(exc))
        return JSONResponse({"ok": True, "result": result})

    async def report(request: Request) -> Response:
        session = request.path_params["session"]
        if not is_name(session):
            return refusal(400, "bad_request", "not a session id")
        try:
            reply = await bridge.request("session.report", session=session)
        except DaemonError as exc:
            return refusal(404 if exc.code else 503, exc.code or "unreachable", str(exc))
        paths = {f["path"] for f in reply["files"]}
        extra: dict[str, Any] = {}
        for path, key, what, make in (
                ("calibration/result.json", "result", "result", result_view),
                ("calibration/live.json", "live", "live calibration",
                 lambda u: live_view(u, bridge.target_m))):
            if path in paths:
                with contextlib.suppress(DaemonError):  # gone since the listing
                    try:
                        extra[key] = make(load_json(await bridge.file(session, path),
                                                    MAX_FILE_BYTES, path))
                    except ViewError as exc:
                        extra[f"{key}_error"] = str(exc)
                    except JsonInputError as exc:
                        extra[f"{key}_error"] = f"this {what} cannot be shown: {exc}"
        return JSONResponse({**reply, **extra})

    async def file(request: Request) -> Response:
        session, path = request.path_params["session"], request.path_params["path"]
        media = MEDIA_TYPES.get(Path(path).suffix.lower())
        if not (is_name(session) and is_relative_path(path)) or media is None:
            return refusal(400, "bad_request", "not a calibration file this page shows")
        try:
            data = await bridge.file(session, path)
        except DaemonError as exc:
            return refusal(404 if exc.code else 503, exc.code or "unreachable", str(exc))
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
        WebSocketRoute(WEBSOCKET_PATH, websocket),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    app = Starlette(routes=routes, lifespan=lifespan,
                    exception_handlers={HTTPException: _http_refusal})
    app.add_middleware(BodyLimit, max_bytes=MAX_BODY_BYTES, timeout_s=request_timeout_s)
    app.add_middleware(AccessGuard, token=token, served=served)
    return app


def parse_command(body: bytes) -> tuple[str, dict[str, Any]]:
    """The command a POST asks for and its arguments (those given as null or "" left out);
    JsonInputError says what is wrong with it."""
    usage = (f"send {{\"command\": NAME, \"args\": {{...}}}} with NAME one of "
             f"{', '.join(COMMANDS)}")
    data = load_json(body, MAX_BODY_BYTES, "the command")
    if not isinstance(data, dict) or not isinstance(data.get("command"), str):
        raise JsonInputError(f"the command is not an object with a \"command\": {usage}")
    name, args = data["command"], data.get("args") or {}
    if name not in COMMANDS:
        raise JsonInputError(f"unknown command {shown(name)}: {usage}")
    unknown = set(data) - {"command", "args", "confirm"}
    if unknown:
        raise JsonInputError(f"{name}: unknown keys {shown(', '.join(sorted(unknown)))}; a "
                             "command has \"command\", \"args\" and \"confirm\"")
    if not isinstance(args, dict) or set(args) - COMMANDS[name]:
        raise JsonInputError(f"{name} takes the arguments "
                             f"{', '.join(sorted(COMMANDS[name])) or '(none)'} in \"args\"")
    if name == "session.abort" and data.get("confirm") is not True:
        raise JsonInputError("aborting ends the session for good: send \"confirm\": true")
    return name, {k: v for k, v in args.items() if v is not None and v != ""}


def _retune_live(bridge: Bridge, args: dict[str, Any]) -> Response:
    """`live.view`: the live view's new controls, or why not."""
    if bridge.live_stream is None:
        return refusal(409, "no_live_view", "this page draws no live maps: start micam web "
                                            "with --geometry result.json")
    try:
        return JSONResponse({"ok": True, "result": bridge.retune_live(args)})
    except LiveViewError as exc:
        return refusal(400, "bad_request", str(exc))


async def _http_refusal(request: Request, exc: Exception) -> Response:
    """A route's refusal (no such route, a method it does not take) with a reason."""
    assert isinstance(exc, HTTPException)
    path = shown(request.url.path)
    message = {404: f"there is nothing at {path} on this page; it serves {ROUTES}",
               405: f"{shown(request.method)} is not a method {path} takes"}.get(
        exc.status_code, str(exc.detail))
    response = refusal(exc.status_code, "not_found" if exc.status_code == 404 else "bad_request",
                       message)
    response.headers.update(exc.headers or {})
    return response


async def _until_closed(ws: WebSocket, browser: Browser) -> None:
    """Read (and ignore) what the page sends until it goes; then end its queue."""
    with contextlib.suppress(Exception):
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
    browser.end()
