"""The page's routes with a fake daemon: a report whose files cannot be shown says why (never
500), every refusal of a route names what is wrong, and the live view's controls are checked
before they change anything."""

from __future__ import annotations

import json

import pytest
from starlette.testclient import TestClient

from imaging.live import LiveSettings
from micam.web.app import create_app
from micam.web.hosts import ServedHosts

from .asgi import HOST, PORT, FakeBridge

RESULT = "calibration/result.json"
LIVE = "calibration/live.json"


def _client(files: dict[str, bytes]) -> TestClient:
    app = create_app(FakeBridge(files).as_bridge(), None, ServedHosts(PORT, "127.0.0.1"), 5.0)
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


def _view(bridge: FakeBridge, args: dict) -> tuple[int, dict]:
    app = create_app(bridge.as_bridge(), None, ServedHosts(PORT, "127.0.0.1"), 5.0)
    reply = TestClient(app, base_url=f"http://{HOST}").post(
        "/api/command", json={"command": "live.view", "args": args})
    return reply.status_code, reply.json()


def test_the_live_view_is_changed_within_its_bounds_and_refused_beyond() -> None:
    bridge = FakeBridge()
    assert bridge.live_stream is not None
    status, data = _view(bridge, {"band_hz": 2000, "fraction": 1, "range_db": 30})
    assert status == 200 and data["result"]["band_hz"] == 2000.0, data
    assert bridge.live_stream.settings == LiveSettings(band_hz=2000.0, fraction=1,
                                                       dynamic_range_db=30.0)
    status, data = _view(bridge, {"band_hz": 3150})  # an octave view has no such band
    assert status == 400 and "not a octave centre" not in data["error"], data
    assert "3150 is not an octave centre; the nearest is 4000 Hz" in data["error"], data
    status, data = _view(bridge, {"band_hz": 3150, "fraction": 3})  # a rounded centre
    assert status == 200 and data["result"]["band_hz"] == pytest.approx(3174.8, abs=0.1)
    for args, why in (({"range_db": 500}, "range_db 500 is not a number from 3 to 60"),
                      ({"range_db": "30"}, "range_db '30' is not a number"),
                      ({"depth_m": True}, "depth_m True is not a number"),
                      ({"band_hz": 3000, "fraction": 3}, "the nearest is 3175 Hz"),
                      ({"fraction": 2}, "1 (octave) or 3 (third octave)"),
                      ({"fraction": 2.9}, "fraction 2.9: 1 (octave) or 3"),
                      ({"window_s": 1}, "live.view takes the arguments")):
        before = bridge.live_stream.settings
        status, data = _view(bridge, args)
        assert status == 400 and why in data["error"], (args, data)
        assert bridge.live_stream.settings == before  # nothing changed


def test_a_page_without_live_maps_says_how_to_have_them() -> None:
    bridge = FakeBridge()
    bridge.live_stream = None  # micam web without --geometry
    status, data = _view(bridge, {"band_hz": 2000})
    assert status == 409 and "--geometry" in data["error"]
