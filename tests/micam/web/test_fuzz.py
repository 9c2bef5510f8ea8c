"""Property-based fuzzing of the page's HTTP API and WebSocket (hypothesis).

Each example is one request with random parts: the method, the path (the page's routes, with
random ids and file paths, and random paths), the query, the headers (Host, Origin, Cookie,
Authorization, Content-Length, Transfer-Encoding, Content-Type, and random ones, each missing,
doubled, malformed or foreign at times), and the body (random bytes, random JSON with deep
nesting, huge numbers and lone surrogates, well-shaped commands with random arguments), in
one piece or several; or a WebSocket with random headers. The application (with and without
a token, behind a fake daemon whose session files are random too) must never answer 500 nor
raise: every answer below 400 is the page's, every refusal a 4xx with a JSON body that says
why, every refused WebSocket a 4xx answer or a close code of 4000 + status.

A few examples go to a real `micam web` (uvicorn) as raw bytes too: it must answer each with
something other than a 5xx (or close the connection) and keep answering.

The default run is bounded (MICAM_FUZZ_EXAMPLES, default 150 in-process and 25 against the
process, a few seconds); `MICAM_LONG_TESTS=1` runs 20 000 and 500 (docs/security.md).
"""

from __future__ import annotations

import json
import os
import socket
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from micam.web.app import COMMANDS, create_app
from micam.web.hosts import ServedHosts
from micam.web.testing import WebProcess

from .asgi import HOST, PORT, Answer, FakeBridge, runner, scope_of
from .raw_http import exchange, head, parse_reply, read_all

LONG = os.environ.get("MICAM_LONG_TESTS") == "1"
EXAMPLES = int(os.environ.get("MICAM_FUZZ_EXAMPLES", "20000" if LONG else "150"))
PROCESS_EXAMPLES = max(1, EXAMPLES // 40) if LONG else min(EXAMPLES, 25)
TOKEN = "s3cret-token-of-the-page"
SESSION = "2026-01-01T00-00-00Z_abcd"

# -- strategies ------------------------------------------------------------------------------

any_text = st.text(alphabet=st.characters(exclude_categories=()), max_size=30)  # surrogates too
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | any_text,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(any_text, inner, max_size=4),
    max_leaves=12)


def _encode(value: Any) -> bytes:
    """JSON text of `value` as a client could send it: NaN and lone surrogates included."""
    return json.dumps(value, ensure_ascii=False).encode("utf-8", "surrogatepass")


def _deep(depth: int, opener: bytes) -> bytes:
    closer = b"]" if opener == b"[" else b"}"
    inner = b'{"a": ' * depth if opener == b"{" else b"[" * depth
    return inner + b"1" + closer * depth


commands = st.builds(
    lambda name, args, confirm, extra: _encode(
        {"command": name, "args": args, **({"confirm": confirm} if confirm is not None else {}),
         **extra}),
    st.sampled_from([*COMMANDS, "launch", ""]),
    st.dictionaries(st.sampled_from(["poses", "resume", "seconds", "cameras", "x"]),
                    json_values, max_size=3) | json_values,
    st.none() | json_values,
    st.dictionaries(any_text, json_values, max_size=1))
bodies = st.one_of(
    st.just(b""), st.binary(max_size=200), commands, json_values.map(_encode),
    st.builds(_deep, st.integers(1, 3000), st.sampled_from([b"[", b"{"])),
    st.integers(10, 5000).map(lambda n: b'{"command": "capture", "n": ' + b"9" * n + b"}"),
    st.sampled_from([b"NaN", b"-Infinity", b"1e999", b'"\\ud800"', b'{"command": "\\udfff"}',
                     b"\xef\xbb\xbf{}", b"\xff\xfe{\x00}\x00", b" " * 5000]))
segment = st.text(alphabet=st.characters(exclude_categories=["Cs"]), min_size=0, max_size=20)
session_ids = st.sampled_from([SESSION, "..", ".hidden", "a/b", "", "x" * 300]) | segment
file_paths = st.sampled_from(["calibration/result.json", "calibration/live.json",
                              "calibration/report.md", "calibration/figures/a.png",
                              "calibration/../journal.jsonl", "calibration/page.html",
                              "journal.jsonl"]) | segment
paths = st.one_of(
    st.sampled_from(["/", "/api/state", "/api/command", "/ws", "/static/app.js",
                     "/static/../app.py", "/static/", "//", "/api/"]),
    st.builds(lambda s: f"/api/sessions/{s}/report", session_ids),
    st.builds(lambda s, p: f"/api/sessions/{s}/files/{p}", session_ids, file_paths),
    st.lists(segment, max_size=4).map(lambda parts: "/" + "/".join(parts)))
methods = st.sampled_from(["GET", "POST", "POST", "HEAD", "PUT", "DELETE", "OPTIONS",
                           "PATCH", "TRACE", "CONNECT", "get", "BREW"])
header_value = st.binary(max_size=60).map(
    lambda b: b.replace(b"\r", b"").replace(b"\n", b"").replace(b"\x00", b"").strip())
hosts = st.sampled_from([HOST.encode()] * 6 + [
    f"localhost:{PORT}".encode(), f"[::1]:{PORT}".encode(), b"evil.example:8765",
    b"127.0.0.1:1", b"localhost", b"", b"[::1", b"127.0.0.1:99999", b"EVIL.example"]) | header_value
origins = st.sampled_from([f"http://{HOST}".encode(), b"http://evil.example:8765", b"null",
                           f"https://{HOST}".encode(), f"http://{HOST}/x".encode(),
                           b"http://[::1", b"file://"]) | header_value
lengths = st.sampled_from([b"0", b"10", b"4096", b"4097", b"999999999999", b"-1", b"1e3",
                           b"0x10", b" 5", b"9" * 30]) | header_value
header_lists = st.fixed_dictionaries(
    {"host": st.just([HOST.encode()]) | st.lists(hosts, max_size=2)},
    optional={
        "origin": st.lists(origins, min_size=1, max_size=2),
        "cookie": st.lists(st.sampled_from([f"micam_token={TOKEN}".encode(), b"micam_token=x",
                                            b"a=b; micam_token=", b";;="]) | header_value,
                           min_size=1, max_size=2),
        "authorization": st.lists(st.sampled_from([f"Bearer {TOKEN}".encode(), b"Bearer",
                                                   b"Basic eA=="]) | header_value,
                                  min_size=1, max_size=2),
        "content-length": st.lists(lengths, min_size=1, max_size=2),
        "transfer-encoding": st.lists(st.sampled_from([b"chunked", b"gzip"]) | header_value,
                                      min_size=1, max_size=1),
        "content-type": st.lists(st.sampled_from(
            [b"application/json"] * 4 + [b"application/json; charset=utf-8", b"text/plain",
                                         b"APPLICATION/JSON", b""]) | header_value,
                                 min_size=1, max_size=2),
        "x-random": st.lists(header_value, min_size=1, max_size=2),
    })
queries = st.sampled_from([b"", b"token=" + TOKEN.encode(), b"token=wrong", b"token=%ff",
                           b"a=1&a=2", b"%"]) | st.binary(max_size=40)
results = st.one_of(
    json_values.map(_encode), bodies,
    st.builds(lambda c, mics: _encode({"speed_of_sound_m_s": c, "microphones": mics}),
              json_values, st.lists(st.fixed_dictionaries(
                  {"id": json_values, "position_m": json_values, "std_m": json_values}),
                  max_size=3)))


def _flatten(headers: dict[str, list[bytes]]) -> list[tuple[bytes, bytes]]:
    return [(name.encode(), value) for name, values in headers.items() for value in values]


def _split(body: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(body) + 1) for c in cuts})
    pieces = [body[a:b] for a, b in zip([0, *points], [*points, len(body)], strict=True)]
    return pieces or [b""]


# -- in process ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def run() -> Iterator[Callable[..., Answer]]:
    call, close = runner()
    yield call
    close()


def _check(answer: Answer, websocket: bool) -> None:
    if websocket and answer.status is None:
        assert answer.accepted or (answer.close_code or 0) >= 4000, answer
        if answer.accepted:
            assert answer.texts and '"snapshot"' in answer.texts[0]
        return
    assert answer.status is not None, "no answer"
    assert answer.status < 500, (answer.status, answer.body[:300])
    if answer.status >= 400:
        data = answer.json()
        assert data["ok"] is False and isinstance(data["error"], str)
        assert len(data["error"]) >= 10 and "\n" not in data["error"], data


@settings(max_examples=EXAMPLES, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                 HealthCheck.function_scoped_fixture])
@given(method=methods, path=paths, query=queries, headers=header_lists, body=bodies,
       cuts=st.lists(st.integers(0, 10_000), max_size=3), websocket=st.booleans(),
       denial=st.booleans(), token=st.sampled_from([None, TOKEN]), result=results,
       live=results)
@pytest.mark.slow
def test_no_request_gets_a_500(run: Callable[..., Answer], method: str, path: str,
                               query: bytes, headers: dict[str, list[bytes]], body: bytes,
                               cuts: list[int], websocket: bool, denial: bool,
                               token: str | None, result: bytes, live: bytes) -> None:
    bridge = FakeBridge({"calibration/result.json": result, "calibration/live.json": live,
                         "calibration/report.md": body})
    app = create_app(bridge.as_bridge(), token, ServedHosts(PORT, "127.0.0.1"), 5.0)
    kind = "websocket" if websocket else "http"
    answer = run(app, scope_of(method, path, _flatten(headers), query, kind, denial),
                 _split(body, cuts))
    _check(answer, websocket)
    if answer.status == 200 and path == "/api/command":
        assert bridge.requests, "a command answered ok reached the daemon"


# -- against the real process ----------------------------------------------------------------


raw_targets = paths.map(lambda p: p.encode("utf-8", "surrogatepass")) | st.sampled_from(
    [b"*", b"http://evil.example/", b"/%00", b"/%ff%fe", b"/?" + b"a" * 2000, b"/ /"])
raw_methods = methods.map(str.encode) | st.binary(min_size=1, max_size=8)


@settings(max_examples=PROCESS_EXAMPLES, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                 HealthCheck.function_scoped_fixture])
@given(method=raw_methods, target=raw_targets, headers=header_lists, body=bodies,
       version=st.sampled_from([b"HTTP/1.1"] * 5 + [b"HTTP/1.0", b"HTTP/2", b"HTTP/1.1x"]),
       chunked=st.booleans())
@pytest.mark.slow
def test_the_running_page_never_answers_5xx(lone_web: WebProcess, method: bytes, target: bytes,
                                            headers: dict[str, list[bytes]], body: bytes,
                                            version: bytes, chunked: bool) -> None:
    ours, real = str(PORT).encode(), str(lone_web.port).encode()  # the page's own port is real's
    headers = {k: [v.replace(ours, real) for v in values] for k, values in headers.items()
               if k not in ("content-length", "transfer-encoding")}
    framing = [b"Transfer-Encoding: chunked"] if chunked else [b"Content-Length: %d" % len(body)]
    lines = [method + b" " + target + b" " + version,
             *[name + b": " + value for name, value in _flatten(headers)], *framing]
    payload = b"%x\r\n%s\r\n0\r\n\r\n" % (len(body), body) if chunked and body else (
        b"0\r\n\r\n" if chunked else body)
    with socket.create_connection(("127.0.0.1", lone_web.port), timeout=5) as sock:
        sock.sendall(b"\r\n".join(lines) + b"\r\n\r\n" + payload)
        reply = parse_reply(read_all(sock, 5.0))
    assert reply.status is None or reply.status < 500 or (
        reply.status == 503 and b"unreachable" in reply.body), reply
    assert lone_web.proc.poll() is None, f"micam web exited; see {lone_web.log}"
    state = head("GET", "/api/state", f"127.0.0.1:{lone_web.port}")
    assert exchange(lone_web.port, state).status == 200

