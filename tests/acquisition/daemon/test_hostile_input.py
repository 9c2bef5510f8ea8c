"""Hostile and broken input at the daemon's sockets: every request is answered, the daemon
neither dies nor goes deaf, and no frame is buffered beyond its socket's limit.

The property-based fuzz test over all four sockets is test_fuzz.py; these are the classes the
fuzzing found, each pinned down as a case.
"""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest
import zmq

from acquisition.daemon.endpoints import beside
from acquisition.daemon.server import Refusal, parse_request
from acquisition.contracts.session import SessionReader

from .helpers import DaemonProcess, ThreadDaemon, capture_all, write_toml

SURROGATE_ID = b'{"v": 2, "command": "ping", "id": "\\ud800"}'


@pytest.mark.parametrize(
    ("raw", "words"),
    [(b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
     (b'{"v": 2, "command": "ping", "args": ' + b'{"a": ' * 5000 + b"1" + b"}" * 5001,
      "nested too deeply"),
     (b'{"v": 2, "command": "ping", "id": ' + b"9" * 5000 + b"}", "digits"),
     (SURROGATE_ID, "id: ")],
)
def test_requests_that_break_a_parser_are_refused_as_bad_requests(raw: bytes, words: str) -> None:
    with pytest.raises(Refusal) as caught:
        parse_request([raw], 1 << 20)
    assert caught.value.code == "bad_request" and words in caught.value.message


def test_a_reply_that_cannot_be_encoded_becomes_an_error_reply(daemon: ThreadDaemon) -> None:
    """The class behind the lone-surrogate crash: whatever a handler returns, the reply is
    encoded inside the guard and the daemon answers the next request."""
    handlers = daemon.daemon._handlers
    handlers["ping"] = lambda _: {"text": "\ud800"}
    with daemon.client() as client:
        reply = client.exchange([b'{"v": 2, "id": "abc", "command": "ping"}'])
        assert not reply.ok and reply.error is not None
        assert reply.error.code == "internal" and reply.id == "abc"
        assert "could not be encoded" in reply.error.message
        assert client.status().state == "idle"
    assert daemon.thread.is_alive()


@pytest.mark.slow
def test_unencodable_ids_neither_stop_nor_deafen_the_daemon(daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        reply = client.exchange([SURROGATE_ID])  # idle: the daemon used to exit here
        assert not reply.ok and reply.error is not None and reply.error.code == "bad_request"
        session = Path(client.request("session.start", poses=2)["session"]["path"])
        for _ in range(3):  # in a session: the REP socket used to be left unable to send
            assert not client.exchange([SURROGATE_ID]).ok
            assert client.status().session is not None
        capture_all(client)
    assert SessionReader(session).status == "complete"


def _peak_rss_bytes(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmHWM in /proc")


@pytest.mark.slow
def test_every_socket_drops_oversized_frames_before_buffering_them(tmp_path: Path) -> None:
    """128 MiB frames at the control, events, jobs and files sockets: the daemon's peak memory
    grows by far less than one of them (ZeroMQ drops each connection at the frame's header),
    and it answers `status` after each."""
    process = DaemonProcess(write_toml(tmp_path / "daemon.toml", tmp_path), tmp_path)
    big = b"x" * (128 * 2**20)
    control = f"ipc://{tmp_path}/control"
    targets = [(zmq.REQ, control), (zmq.XSUB, f"ipc://{tmp_path}/events"),
               (zmq.DEALER, beside(control, "jobs")), (zmq.DEALER, beside(control, "files"))]
    context = zmq.Context()
    try:
        process.wait_message("READY=1")
        with process.client() as client:
            client.status()
            before = _peak_rss_bytes(process.proc.pid)
            for kind, endpoint in targets:
                sock = context.socket(kind)
                sock.linger = 0
                sock.connect(endpoint)
                # (An XSUB frame not starting with 0 or 1 is not a subscription, which the XSUB
                # itself would parse: libzmq crashes the sender on a 128 MiB topic.)
                tracker = sock.send(big, copy=False, track=True)
                tracker.wait(30)  # ZeroMQ is done with it: sent, or dropped with the link
                time.sleep(0.2)  # let the daemon's I/O thread take whatever it would take
                sock.close()
                assert client.status().state == "idle", endpoint
            grown = _peak_rss_bytes(process.proc.pid) - before
    finally:
        context.destroy(linger=0)
        process.kill()
    assert grown < 32 * 2**20, f"the daemon's peak memory grew by {grown / 2**20:.0f} MiB"


def test_raw_bytes_into_the_control_socket_file_do_not_deafen_the_daemon(
        daemon: ThreadDaemon) -> None:
    """Found by test_fuzz: bytes below ZeroMQ's framing (read as ZMTP 1.0 frames) used to
    leave a REP control socket sending its replies to nobody."""
    digits = b'{"v": 2, "command": "ping", "id": ' + b"9" * 5000 + b"}"
    raw_bytes = digits + b"[" * 4000 + b"]" * 4000 + digits
    path = daemon.config.sockets.control.removeprefix("ipc://")
    with daemon.client(timeout_s=5.0) as client:
        for _ in range(3):
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as raw:
                raw.connect(path)
                raw.sendall(raw_bytes)
            assert client.status().state == "idle"
