"""Who may open the page: loopback by default, a token otherwise; in every mode only under a
name the page serves (Host), and changes only from the page itself (Origin)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from starlette.testclient import TestClient, WebSocketDenialResponse

from acquisition.contracts.errors import UserError
from micam.cli import main
from micam.web.access import check_listen, read_token
from micam.web.app import create_app
from micam.web.hosts import ServedHosts

from .asgi import HOST, PORT, FakeBridge, runner, scope_of

TOKEN = "s3cret-token-of-the-page"
SERVED = ServedHosts(PORT, "127.0.0.1")
SAME = {"host": HOST, "origin": f"http://{HOST}"}
EVIL = {"host": f"evil.example:{PORT}", "origin": f"http://evil.example:{PORT}"}
COMMAND = {"command": "session.start", "args": {"poses": 2}}


def _client(token: str | None) -> tuple[TestClient, FakeBridge]:
    bridge = FakeBridge()
    app = create_app(bridge.as_bridge(), token, SERVED, 5.0)
    return TestClient(app, base_url=f"http://{HOST}"), bridge


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
    for bad in ("short", "pässwörd-of-the-page-€", "token with spaces in it", "a+b/c=" * 4):
        path.write_text(bad)
        with pytest.raises(UserError, match="at least 16 letters, digits or"):
            read_token(path)


def test_the_token_is_asked_for_and_kept_in_a_cookie() -> None:
    client, _ = _client(TOKEN)
    assert client.get("/api/state").status_code == 401
    assert client.get("/", params={"token": "wrong-token-wrong-token"}).status_code == 401
    reply = client.get("/", params={"token": TOKEN}, follow_redirects=False)
    assert reply.status_code == 303 and reply.headers["location"] == "/"
    assert "HttpOnly" in reply.headers["set-cookie"] and "SameSite=Strict" in reply.headers[
        "set-cookie"]
    assert client.get("/api/state").status_code == 200  # the cookie now
    bearer, _ = _client(TOKEN)
    assert bearer.get("/api/state", headers={"authorization": f"Bearer {TOKEN}"}
                      ).status_code == 200
    assert "content-security-policy" in client.get("/api/state").headers
    open_page, _ = _client(None)  # no token: ?token= is no address to redirect from
    for given in ("%ff", "x", TOKEN):
        reply = open_page.get(f"/?token={given}", follow_redirects=False)
        assert reply.status_code == 200 and "set-cookie" not in reply.headers


@pytest.mark.parametrize("token", [None, TOKEN])
def test_a_foreign_host_is_refused_in_every_mode(token: str | None) -> None:
    """DNS rebinding: a page of evil.example resolved to 127.0.0.1 sends the page requests
    with its own name in Host and Origin. GET, POST and the WebSocket are refused (421), with
    the token too, and nothing reaches the daemon."""
    client, bridge = _client(token)
    auth = {"authorization": f"Bearer {TOKEN}"} if token else {}
    for reply in (client.get("/api/state", headers={**EVIL, **auth}),
                  client.get("/", headers={**EVIL, **auth}),
                  client.get("/static/app.js", headers={**EVIL, **auth}),
                  client.post("/api/command", json=COMMAND, headers={**EVIL, **auth})):
        assert reply.status_code == 421, reply.text
        assert "evil.example" in reply.json()["error"] and "\n" not in reply.json()["error"]
        assert "content-security-policy" in reply.headers
    with pytest.raises(WebSocketDenialResponse) as refused, client.websocket_connect(
            "/ws", headers={**EVIL, **auth}) as ws:
        ws.receive_text()
    assert refused.value.status_code == 421 and "evil.example" in refused.value.json()["error"]
    assert bridge.requests == []


def test_the_host_header_must_be_there_once_and_well_formed() -> None:
    run, close = runner()
    app = create_app(FakeBridge().as_bridge(), None, SERVED, 5.0)
    try:
        for headers in ([], [(b"host", HOST.encode()), (b"host", HOST.encode())],
                        [(b"host", b"local host:8765")], [(b"host", b"[::1:8765")]):
            answer = run(app, scope_of("GET", "/api/state", headers))
            assert answer.status == 400 and "Host" in answer.json()["error"], headers
        for kind in ("websocket",):  # a WebSocket without Host: the same answer
            answer = run(app, scope_of("GET", "/ws", [], kind=kind))
            assert answer.status == 400 and not answer.accepted
            answer = run(app, scope_of("GET", "/ws", [], kind=kind, denial=False))
            assert answer.close_code == 4400 and not answer.accepted
        answer = run(app, scope_of("GET", "/api/state", [(b"host", b"LOCALHOST:8765")]))
        assert answer.status == 200
        answer = run(app, scope_of("GET", "/api/state", [(b"host", b"[::1]:8765")]))
        assert answer.status == 200
        for port in (b"8766", b"80"):
            answer = run(app, scope_of("GET", "/api/state", [(b"host", b"localhost:" + port)]))
            assert answer.status == 421
        forwarded = [(b"host", b"evil.example:8765"), (b"x-forwarded-host", HOST.encode())]
        assert run(app, scope_of("GET", "/api/state", forwarded)).status == 421
    finally:
        close()


def test_changes_reads_and_the_websocket_come_from_the_page_itself() -> None:
    client, bridge = _client(None)
    assert client.post("/api/command", json=COMMAND, headers=SAME).status_code == 200
    assert bridge.requests == [("session.start", {"poses": 2})]
    for origin in ("http://evil.example", f"http://localhost:{PORT}", "null"):
        for reply in (client.post("/api/command", json=COMMAND, headers={"origin": origin}),
                      client.get("/api/state", headers={"origin": origin})):
            assert reply.status_code == 403 and "another site" in reply.json()["error"]
    assert len(bridge.requests) == 1
    with client.websocket_connect("/ws", headers=SAME) as ws:
        assert '"snapshot"' in ws.receive_text()
    with pytest.raises(WebSocketDenialResponse) as refused, client.websocket_connect(
            "/ws", headers={"host": HOST, "origin": "http://evil.example"}) as ws:
        ws.receive_text()
    assert refused.value.status_code == 403


def test_a_command_is_json_of_the_page() -> None:
    """A form (text/plain, urlencoded) cannot carry a command: a cross-site form cannot post
    one even where Origin is not sent, and a cross-site fetch of JSON needs CORS, which the
    page never grants."""
    client, bridge = _client(None)
    for kind in ("text/plain", "application/x-www-form-urlencoded", "multipart/form-data"):
        reply = client.post("/api/command", content=b'{"command": "capture"}',
                            headers={"content-type": kind})
        assert reply.status_code == 415 and "application/json" in reply.json()["error"]
    assert bridge.requests == []
    deep = b'{"command": "capture", "args": ' + b"[" * 1000 + b"]" * 1000 + b"}"
    for body, why in ((deep, "deep"), (b'{"command": "capture", "args": {"x": NaN}}', "NaN"),
                      (b'{"command": "capture", "args": {"x": 1e999}}', "too large"),
                      (b'{"command": "capture", "args": {"x": "\\ud800"}}', "surrogate"),
                      (b'{"command": "capture", "n": ' + b"9" * 30 + b"}", "digits"),
                      (b'\xff\xfe', "UTF-8"), (b'[1, 2]', "an object"),
                      (b'{"command": "launch"}', "unknown command"),
                      (b'{"command": "capture", "args": {"poses": 3}}', "arguments"),
                      (b'{"command": "session.abort"}', "confirm")):
        reply = client.post("/api/command", content=body,
                            headers={"content-type": "application/json"})
        assert reply.status_code == 400 and why in reply.json()["error"], (body[:40], reply.text)
    assert bridge.requests == []


@pytest.mark.parametrize(("argv", "why"), [
    (["--allow-host", "http://rig-pc.example"], "--allow-host http://rig-pc.example: give"),
    (["--listen", "127.0.0.1:0"], "port from 1 to 65535"),
    (["--listen", "127.0.0.1:٨٠"], "port from 1 to 65535"),
])
def test_bad_options_are_one_line_errors(argv: list[str], why: str,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["web", "--control", "ipc:///nonexistent/control", *argv]) == 2
    error = capsys.readouterr().err
    assert error.startswith("micam: error: ") and why in error and error.count("\n") == 1
