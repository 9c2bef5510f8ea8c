"""Who may open the page: loopback by default, a token otherwise, the same origin for changes."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from starlette.applications import Starlette
from starlette.responses import PlainTextResponse
from starlette.routing import Route, WebSocketRoute
from starlette.testclient import TestClient
from starlette.websockets import WebSocket, WebSocketDisconnect

from acquisition.contracts.errors import UserError
from micam.web.access import check_listen, read_token
from micam.web.app import AccessGuard

TOKEN = "s3cret-token-of-the-page"


def _app(token: str | None) -> TestClient:
    async def page(_request: object) -> PlainTextResponse:
        return PlainTextResponse("the page")

    async def ws(socket: WebSocket) -> None:
        await socket.accept()
        await socket.send_text("hello")
        await socket.close()

    app = Starlette(routes=[Route("/", page), Route("/api/command", page, methods=["POST"]),
                            WebSocketRoute("/ws", ws)])
    app.add_middleware(AccessGuard, token=token)
    return TestClient(app, base_url="http://page.test")


def test_off_loopback_needs_a_token() -> None:
    check_listen("127.0.0.1", None)
    check_listen("::1", None)
    with pytest.raises(UserError, match="without a token"):
        check_listen("0.0.0.0", None)
    check_listen("0.0.0.0", TOKEN)


def test_a_token_file_must_be_private_and_long_enough(tmp_path: Path) -> None:
    path = tmp_path / "token"
    path.write_text(TOKEN + "\n")
    os.chmod(path, 0o644)
    with pytest.raises(UserError, match="chmod 600"):
        read_token(path)
    os.chmod(path, 0o600)
    assert read_token(path) == TOKEN
    path.write_text("short")
    with pytest.raises(UserError, match="at least 16"):
        read_token(path)


def test_the_token_is_asked_for_and_kept_in_a_cookie() -> None:
    client = _app(TOKEN)
    assert client.get("/").status_code == 401
    assert client.get("/", params={"token": "wrong-token-wrong-token"}).status_code == 401
    reply = client.get("/", params={"token": TOKEN}, follow_redirects=False)
    assert reply.status_code == 303 and reply.headers["location"] == "/"
    assert "HttpOnly" in reply.headers["set-cookie"] and "SameSite=Strict" in reply.headers[
        "set-cookie"]
    assert client.get("/").text == "the page"  # the cookie now
    assert _app(TOKEN).get("/", headers={"authorization": f"Bearer {TOKEN}"}).status_code == 200
    assert "content-security-policy" in client.get("/").headers


def test_changes_and_the_websocket_come_from_the_page_itself() -> None:
    client = _app(None)
    assert client.post("/api/command", headers={"origin": "http://page.test"}).status_code == 200
    assert client.post("/api/command", headers={"origin": "http://evil.test"}).status_code == 403
    same = {"origin": "http://page.test", "host": "page.test"}
    with client.websocket_connect("/ws", headers=same) as ws:
        assert ws.receive_text() == "hello"
    with pytest.raises(WebSocketDisconnect) as refused, client.websocket_connect(
            "/ws", headers={**same, "origin": "http://evil.test"}) as ws:
        ws.receive_text()
    assert refused.value.code == 4403
