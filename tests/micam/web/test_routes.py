"""The page's routes with a fake daemon: a report whose files cannot be shown says why (never
500), and every refusal of a route names what is wrong."""

from __future__ import annotations

import json

import pytest
from starlette.testclient import TestClient

from micam.web.app import create_app
from micam.web.hosts import ServedHosts

from .asgi import HOST, PORT, FakeBridge

RESULT = "calibration/result.json"
LIVE = "calibration/live.json"


def _client(files: dict[str, bytes]) -> TestClient:
    app = create_app(FakeBridge(files), None, ServedHosts(PORT, "127.0.0.1"), 5.0)
    return TestClient(app, base_url=f"http://{HOST}")


@pytest.mark.parametrize(("content", "why"), [
    (b'{"speed_of_sound_m_s": NaN, "microphones": []}', "NaN"),
    (b'{"speed_of_sound_m_s": Infinity, "microphones": []}', "Infinity"),
    (b'{"speed_of_sound_m_s": 1e999, "microphones": []}', "too large"),
    (b"[" * 1000 + b"]" * 1000, "deep"),
    (b'"a string"', "valid dictionary"),
    (b'{"speed_of_sound_m_s": 343, "microphones": [{"id": [], "position_m": 1}]}', "id"),
    (b'{"speed_of_sound_m_s": 343, "microphones": null}', "microphones"),
    (b'{"speed_of_sound_m_s": "fast", "microphones": []}', "speed_of_sound_m_s"),
    (b"\x89PNG", "UTF-8"),
    (b'{"unterminated": ', "not JSON"),
])
def test_a_result_that_cannot_be_shown_is_reported_not_a_500(content: bytes, why: str) -> None:
    reply = _client({RESULT: content, LIVE: content}).get("/api/sessions/s1/report")
    assert reply.status_code == 200, reply.text
    data = reply.json()
    assert "result" not in data and "live" not in data
    assert data["result_error"].startswith("this result cannot be shown: ")
    assert data["live_error"].startswith("this live calibration cannot be shown: ")
    assert why in data["result_error"], data["result_error"]


def test_a_result_that_can_be_shown_is() -> None:
    result = {"session_id": "s1", "method": "joint", "speed_of_sound_m_s": 343.1,
              "microphones": [{"id": 1, "position_m": [0, 0, 1], "std_m": [1e-4, 0, 0]}]}
    reply = _client({RESULT: json.dumps(result).encode()}).get("/api/sessions/s1/report")
    assert reply.json()["result"]["n_microphones"] == 1 and "result_error" not in reply.json()


def test_every_refusal_of_a_route_says_why() -> None:
    client = _client({})
    for method, path, status, why in (
            ("GET", "/nothing-here", 404, "there is nothing at '/nothing-here'"),
            ("GET", "/static/none.js", 404, "nothing at"),
            ("GET", "/api/command", 405, "'GET' is not a method"),
            ("DELETE", "/api/state", 405, "'DELETE'"),
            ("GET", "/api/sessions/.hidden/report", 400, "session id"),
            ("GET", "/api/sessions/s1/files/calibration/page.html", 400, "calibration file"),
            ("GET", "/api/sessions/s1/files/calibration/none.png", 404, "cannot open"),
    ):
        reply = client.request(method, path)
        assert reply.status_code == status and why in reply.json()["error"], (path, reply.text)
