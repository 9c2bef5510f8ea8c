"""Property-based fuzzing of the daemon's four sockets while a capture runs (hypothesis).

Each example throws one random message at one socket: random bytes, JSON in several text
encodings (lone surrogates included), documents nested tens of thousands deep, integers of
thousands of digits, frames at and around every size limit, several frames at once, well-
shaped requests and worker messages with random fields, or raw bytes straight into an ipc
socket file (below ZeroMQ's framing). After every example the daemon must answer `status`;
the control and files sockets must also answer the message itself whenever it fits their
size limit. Meanwhile the test keeps a capture going (a `capture` whenever the daemon waits
for one), and at the end the session must be complete and intact.

The default run is bounded (MICAM_FUZZ_EXAMPLES, default 150, a few seconds); the long run is
`MICAM_LONG_TESTS=1` (20 000 examples, a few minutes), see docs/security.md.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path

import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acquisition.daemon.endpoints import beside, ipc_path
from acquisition.daemon.files import MAX_FETCH_BYTES
from acquisition.contracts.protocol import Reply, StatusResult
from acquisition.daemon.server import control_hard_limit
from acquisition.contracts.session import SessionReader

from .helpers import ThreadDaemon, capture_all

LONG = os.environ.get("MICAM_LONG_TESTS") == "1"
EXAMPLES = int(os.environ.get("MICAM_FUZZ_EXAMPLES", "20000" if LONG else "150"))
REPLY_WAIT_MS = 10_000  # an answer the daemon owes: served between files, well within this
NO_REPLY_WAIT_MS = 20  # a message that needs no answer: collect one if it comes at once
WAITING = {"references", "reference_microphone", "waiting_for_pose"}
SIZES = [0, 1, 1023, 1025, 4095, 4097, 65_535, 65_537, 2**20 - 1, 2**20 + 1, 8 * 2**20 + 1]

# -- strategies ------------------------------------------------------------------------------

any_text = st.text(alphabet=st.characters(exclude_categories=()), max_size=40)  # surrogates too
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | any_text,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(any_text, inner, max_size=4),
    max_leaves=16)
commands = st.sampled_from(["ping", "status", "sessions.list", "session.start", "launch", ""])
requests = st.fixed_dictionaries(
    {"v": st.sampled_from([1, 1, 1, 0, 2, "1", None, 1.0, True]), "command": commands},
    optional={"id": any_text | json_values, "args": json_values, "extra": json_values})
worker_types = st.sampled_from(["ready", "heartbeat", "progress", "live", "done", "failed",
                                "error", "bye", "fetch", "job", ""])
worker_messages = st.fixed_dictionaries(
    {"v": st.sampled_from([1, 1, 2, None]), "type": worker_types},
    optional={"worker": any_text, "job_id": any_text | json_values, "attempt": json_values,
              "path": any_text, "offset": json_values, "length": json_values,
              "result_sha256": any_text, "reason": any_text, "stage": any_text,
              "retryable": json_values, "update": json_values})
encodings = st.sampled_from(["utf-8", "utf-16", "utf-32", "latin-1", "utf-8-sig"])


@st.composite
def encoded(draw: st.DrawFn, documents: st.SearchStrategy) -> bytes:
    text = json.dumps(draw(documents), ensure_ascii=draw(st.booleans()))
    codec = draw(encodings)
    return text.encode(codec, errors="surrogatepass" if codec.startswith("utf") else "replace")


def _nested(n: int, kind: str) -> bytes:
    if kind == "list":
        return b"[" * n + b"]" * n
    return b'{"v": 2, "command": "ping", "args": ' + b'{"a": ' * n + b"1" + b"}" * (n + 1)


frames = st.one_of(
    st.binary(max_size=256),
    encoded(requests),
    encoded(worker_messages),
    encoded(json_values),
    st.builds(_nested, st.integers(1, 60_000), st.sampled_from(["list", "object"])),
    st.integers(4000, 6000).map(
        lambda n: b'{"v": 2, "command": "ping", "id": ' + b"9" * n + b"}"),
    st.sampled_from(SIZES).map(lambda n: b"x" * n),
)
messages = st.lists(frames, min_size=1, max_size=3)
targets = st.sampled_from(["control", "events", "jobs", "files", "raw"])


# -- the daemon and its capture --------------------------------------------------------------


class Target:
    """The daemon's endpoints and a context to reach them with fresh sockets."""

    def __init__(self, daemon: ThreadDaemon) -> None:
        sockets = daemon.config.sockets
        self.endpoints = {"control": sockets.control, "events": sockets.events,
                          "jobs": beside(sockets.control, "jobs"),
                          "files": beside(sockets.control, "files")}
        self.control_limit = control_hard_limit(sockets.max_message_bytes)
        self.context = zmq.Context()

    def throw(self, target: str, message: list[bytes]) -> None:
        """Send `message` to `target`; assert the answer the daemon owes, if it owes one."""
        if target == "raw":
            self._raw(b"".join(message))
            return
        kind = zmq.XSUB if target == "events" else zmq.DEALER
        sock = self.context.socket(kind)
        sock.linger = 0
        sock.connect(self.endpoints[target])
        try:
            if target == "control":  # a REQ's envelope: the empty delimiter frame
                sock.send_multipart([b"", *message])
                owed = all(len(f) <= self.control_limit for f in message)
                self._expect(sock, owed, lambda frames: Reply.model_validate_json(frames[-1]))
            elif target == "files":
                sock.send_multipart(message)
                owed = all(len(f) <= MAX_FETCH_BYTES for f in message)
                self._expect(sock, owed, lambda frames: json.loads(frames[0])["type"])
            else:  # an XSUB parses a frame starting with 0 or 1 as a subscription: keep it small
                sock.send_multipart([b"x" + f if f[:1] in (b"\0", b"\1") and len(f) > 1024
                                     else f for f in message])
                sock.poll(NO_REPLY_WAIT_MS)
        finally:
            sock.close()

    @staticmethod
    def _expect(sock: zmq.Socket, owed: bool, read) -> None:
        if sock.poll(REPLY_WAIT_MS if owed else NO_REPLY_WAIT_MS):
            read(sock.recv_multipart())
        else:
            assert not owed, "the daemon did not answer a message within its size limit"

    def _raw(self, data: bytes) -> None:
        path = ipc_path(self.endpoints["control"])
        assert path is not None
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as raw:
            raw.settimeout(1.0)
            raw.connect(str(path))
            try:
                raw.sendall(data[:65_536])
            except OSError:  # ZeroMQ hung up on the garbage: that is its right
                pass

    def close(self) -> None:
        self.context.destroy(linger=0)


@pytest.mark.slow
def test_random_input_at_every_socket_during_a_capture(daemon: ThreadDaemon) -> None:
    target = Target(daemon)
    client = daemon.client(timeout_s=10.0)
    started = client.request("session.start", poses=3)["session"]
    session = Path(started["path"])
    every = max(1, EXAMPLES // started["steps_total"])  # spread the steps over the examples
    captures = {"asked": 0, "examples": 0}

    def idle(status: StatusResult) -> bool:
        """Waiting for the operator, and the last capture asked for has ended (its state
        stays waiting for a moment after the request, until the capture starts)."""
        finished = status.last_capture.number if status.last_capture else 0
        return status.state in WAITING and status.captures_requested == finished

    @settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=not LONG,
              suppress_health_check=list(HealthCheck))
    @given(where=targets, message=messages)
    def one(where: str, message: list[bytes]) -> None:
        target.throw(where, message)
        status = client.status()  # must answer after every example
        captures["examples"] += 1
        if captures["examples"] % every == 0 and idle(status):
            captures["asked"] = client.request("capture")["number"]  # keep the capture going

    try:
        one()
        # a capture asked for by the last examples may not have started yet: "cannot
        # capture while capturing" once failed the run below
        status = client.wait_until(lambda s: s.session is None or idle(s), 60.0)
        if status.session is not None:
            status = capture_all(client)
    finally:
        target.close()
        client.close()
    assert status.session is None and captures["asked"] > 1
    reader = SessionReader(session)
    assert reader.status == "complete" and reader.verify() == []
