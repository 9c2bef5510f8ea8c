"""Bounded send queues: a peer that stops reading costs the daemon (and the worker) at most a
few messages, never ZeroMQ's default of 1000 per connection (docs/protocol.md, Sockets).

The ceiling is measured where it matters: the resident memory (/proc/PID/status VmRSS) of a
real daemon process in live mode while five `samples` subscribers never read, with a reading
subscriber and an event subscriber beside them that must keep receiving.
"""

from __future__ import annotations

import time
from contextlib import ExitStack, closing
from pathlib import Path
from typing import cast

import pytest
import zmq

from acquisition.contracts.protocol import LIVE_FRAME_TOPIC, SAMPLES_TOPIC
from acquisition.daemon.files import CHUNK_QUEUE
from acquisition.daemon.server import EVENTS_QUEUE
from acquisition.live.mode import BLOCK_SAMPLES
from acquisition.contracts.job_messages import FETCH_WINDOW
from calibration.worker.worker import Worker, WorkerSettings

from .helpers import WAIT_S, DaemonProcess, ThreadDaemon, rss_bytes, write_toml

MAX_QUEUE = 16
"""The longest queue any socket of the daemon or the worker may have, in messages (ZeroMQ's
default is 1000; 0 would be no limit at all)."""
STALLED = 5
STALL_S = 4.0  # ZeroMQ's default queues grew the daemon by 9 MiB a second here
MARGIN_BYTES = 8 * 2**20
"""What the daemon's memory may wander by besides the queues (allocator, Python objects)."""


def _check_queues(sockets: list[zmq.Socket], whose: str) -> None:
    assert sockets, f"{whose} has no sockets"
    for sock in sockets:
        kind = zmq.SocketType(cast(int, sock.type)).name  # pyzmq types options int | bytes
        for option in ("sndhwm", "rcvhwm"):
            value = cast(int, sock.get(getattr(zmq, option.upper())))
            assert 1 <= value <= MAX_QUEUE, f"{whose}'s {kind} socket has {option} {value}"


def test_every_socket_of_the_daemon_has_short_queues(daemon: ThreadDaemon) -> None:
    # pyzmq keeps a context's sockets in `_sockets`: every socket the daemon made, however made
    _check_queues(list(daemon.daemon.server._context._sockets), "the daemon")


def test_every_socket_of_the_worker_has_short_queues(tmp_path: Path) -> None:
    worker = Worker(WorkerSettings(jobs=f"ipc://{tmp_path}/jobs", files=f"ipc://{tmp_path}/f",
                                   name="w", cache=tmp_path / "cache"))
    try:
        worker._connect()  # the jobs socket (the file socket is made per job, as checked below)
        _check_queues(list(worker._context._sockets), "the worker")
    finally:
        worker._context.destroy(linger=0)
    # ZeroMQ updates a writer's count of what was read every half queue: a queue holds a
    # window for sure only if it is twice as long
    assert 2 * FETCH_WINDOW <= CHUNK_QUEUE, "a worker's window of fetches must fit the queue"


@pytest.mark.slow
def test_stalled_samples_subscribers_cost_a_few_blocks(tmp_path: Path) -> None:
    process = DaemonProcess(write_toml(tmp_path / "daemon.toml", tmp_path), tmp_path)
    with ExitStack() as stack:
        stack.callback(process.kill)
        process.wait_message("READY=1")
        client = stack.enter_context(process.client())
        client.request("live.start", seconds=1.0)
        # the rings fill within their second; then the daemon's memory is its working size
        status = client.wait_until(lambda s: s.live is not None and s.live.frames >= 25,
                                   WAIT_S, interval_s=0.05)
        base = rss_bytes(process.proc.pid)
        context = zmq.Context()
        stack.callback(context.destroy, linger=0)
        for _ in range(STALLED):  # subscribe, then never read: ZeroMQ fills what it may
            stalled = context.socket(zmq.SUB)
            stalled.rcvhwm = 1
            stalled.linger = 0
            stalled.subscribe(SAMPLES_TOPIC.encode())
            stalled.connect(client.events_endpoint())
        reader = stack.enter_context(closing(client.topic_socket((SAMPLES_TOPIC,))))
        events = stack.enter_context(closing(client.subscribe(previews=True)))
        blocks, block_bytes, frames, peak = 0, 0, 0, base
        deadline = time.monotonic() + STALL_S
        while time.monotonic() < deadline:
            if reader.poll(10):
                message = reader.recv_multipart()
                blocks += 1
                block_bytes = max(block_bytes, sum(len(frame) for frame in message))
            event = events.next(0.0)
            frames += event is not None and event.type == LIVE_FRAME_TOPIC
            peak = max(peak, rss_bytes(process.proc.pid))
        client.request("live.stop")
    ceiling = STALLED * (EVENTS_QUEUE + 2) * block_bytes + MARGIN_BYTES
    assert peak - base <= ceiling, (
        f"the daemon grew by {(peak - base) / 2**20:.1f} MiB with {STALLED} stalled "
        f"subscribers; at most {ceiling / 2**20:.1f} MiB ({EVENTS_QUEUE} + 2 blocks of "
        f"{block_bytes} bytes each, + {MARGIN_BYTES / 2**20:g} MiB)")
    assert status.live is not None
    expected = STALL_S * status.live.sample_rate_hz / BLOCK_SAMPLES
    assert blocks >= expected / 4, f"the reading subscriber got {blocks} of ~{expected:.0f}"
    assert frames >= 5, f"the event subscriber got {frames} live frames in {STALL_S:g} s"
