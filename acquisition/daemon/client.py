"""The client side of the protocol, for the `micam` commands and for tests.

Each request uses a fresh REQ socket and one bounded wait (the zguide's "lazy pirate" without
the retry: `capture` must not be sent twice). No reply within the timeout is an error that says
what to check; the socket is then discarded, so a late reply can never be mistaken for the
answer to a later request.
"""

from __future__ import annotations

import argparse
import json
import math
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zmq
from pydantic import ValidationError

from acquisition.contracts.errors import UserError
from .endpoints import default_control
from acquisition.contracts.keys import secure_client
from acquisition.contracts.protocol import (
    EVENT_ADAPTER,
    EVENT_TOPICS,
    LIVE_FRAME_TOPIC,
    PREVIEW_TOPIC,
    PROTOCOL_VERSION,
    Event,
    Reply,
    StatusResult,
)


LIVE_QUEUE = 64
"""Messages a `topic_socket` holds unread: 1.4 s of `samples` blocks at 96 kS/s (19 MB at 73
columns), enough for a live view's slow first map."""


class DaemonError(UserError):
    """The daemon refused a request (`code` from the protocol) or could not be reached."""

    def __init__(self, message: str, code: str | None = None) -> None:
        super().__init__(message)
        self.code = code


class EventStream:
    """A subscription to the daemon's events (every type)."""

    def __init__(self, socket: zmq.Socket) -> None:
        self._socket = socket

    def next(self, timeout_s: float) -> Event | None:
        """The next event, or None if none arrives within `timeout_s`."""
        if not self._socket.poll(round(timeout_s * 1000), zmq.POLLIN):
            return None
        _topic, payload = self._socket.recv_multipart()
        return EVENT_ADAPTER.validate_json(payload)

    def close(self) -> None:
        self._socket.close(linger=0)


class DaemonClient:
    """Talks to one daemon: `request` for control, `subscribe` for events."""

    def __init__(self, control: str | None = None, events: str | None = None,
                 timeout_s: float = 5.0, server_key: Path | None = None,
                 client_key: Path | None = None) -> None:
        if (server_key is None) != (client_key is None):
            raise UserError("CURVE needs both --server-key (the daemon's public key) and "
                            "--client-key (your secret key)")
        self.control = control or default_control()
        self.events = events
        self.timeout_s = timeout_s
        self._keys = (server_key, client_key)
        self._context = zmq.Context()

    def __enter__(self) -> DaemonClient:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._context.destroy(linger=0)

    def _socket(self, kind: int, endpoint: str, context: zmq.Context | None = None,
                topics: tuple[str, ...] = (), queue: int | None = None) -> zmq.Socket:
        """A socket of `context` (default this client's) connected to `endpoint`, CURVE when
        keys were given, subscribed to `topics` (a SUB socket), holding at most `queue`
        received messages (set before connect, or it never applies; None: ZeroMQ's 1000)."""
        sock = (context or self._context).socket(kind)
        sock.linger = 0
        if queue is not None:
            sock.rcvhwm = queue
        server_key, client_key = self._keys
        if server_key is not None and client_key is not None:
            secure_client(sock, server_key, client_key)
        for topic in topics:
            sock.subscribe(topic.encode())
        sock.connect(endpoint)
        return sock

    def exchange(self, frames: list[bytes]) -> Reply:
        """Send raw frames and return the reply (tests send malformed requests with this)."""
        sock = self._socket(zmq.REQ, self.control)
        try:
            sock.send_multipart(frames)
            if not sock.poll(round(self.timeout_s * 1000), zmq.POLLIN):
                raise DaemonError(
                    f"no reply from the daemon at {self.control} within {self.timeout_s:g} s; is "
                    "`micam daemon` running there (and, with CURVE, is your key authorised)?")
            raw = sock.recv()
        finally:
            sock.close(linger=0)
        try:
            return Reply.model_validate_json(raw)
        except ValidationError as exc:
            raise DaemonError(f"the daemon at {self.control} sent a reply this client cannot "
                              f"read (another protocol version?): {exc}") from None

    def request(self, command: str, **args: Any) -> dict[str, Any]:
        """Send one command; its result, or DaemonError with the daemon's refusal."""
        message = {"v": PROTOCOL_VERSION, "id": uuid.uuid4().hex[:12], "command": command,
                   "args": {k: v for k, v in args.items() if v is not None}}
        reply = self.exchange([json.dumps(message).encode()])
        if not reply.ok:
            assert reply.error is not None
            raise DaemonError(reply.error.message, reply.error.code)
        return reply.result or {}

    def status(self) -> StatusResult:
        return StatusResult.model_validate(self.request("status"))

    def events_endpoint(self) -> str:
        """The event socket: as given, else as the daemon's `status` reports it."""
        return self.events or _reachable(self.status().events_endpoint, self.control)

    def subscribe(self, previews: bool = False) -> EventStream:
        """Subscribe to every event, camera previews only if `previews` (they are large)."""
        return EventStream(self.event_socket(previews))

    def event_socket(self, previews: bool = False,
                     context: zmq.Context | None = None) -> zmq.Socket:
        """A SUB socket (of `context`, default this client's) on the daemon's events,
        subscribed to every topic, `preview` and `live_frame` only if `previews`."""
        topics = tuple(t for t in EVENT_TOPICS
                       if previews or t not in (PREVIEW_TOPIC, LIVE_FRAME_TOPIC))
        return self._socket(zmq.SUB, self.events_endpoint(), context, topics)

    def topic_socket(self, topics: tuple[str, ...]) -> zmq.Socket:
        """A SUB socket on the daemon's events subscribed to exactly `topics` (live mode's
        `samples` and `live_frame`, which `event_socket` leaves out or cannot parse), holding
        at most LIVE_QUEUE received messages: a reader slower than the stream loses the
        oldest news instead of falling ever further behind (and growing by 14 MB a second)."""
        return self._socket(zmq.SUB, self.events_endpoint(), None, topics, LIVE_QUEUE)

    def wait_until(self, done: Callable[[StatusResult], bool], timeout_s: float,
                   on_event: Callable[[Event], None] | None = None,
                   stream: EventStream | None = None, interval_s: float = 0.2) -> StatusResult:
        """Poll `status` until `done(status)`, passing events to `on_event` meanwhile; raise
        DaemonError after `timeout_s`. Events are only shown; `status` decides (a subscriber
        may miss events, a status reply is never lost)."""
        deadline = time.monotonic() + timeout_s
        for _ in range(math.ceil(timeout_s / interval_s) + 1):  # bounded in count and time
            status = self.status()
            if done(status):
                return status
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            pause_until = time.monotonic() + min(interval_s, remaining)
            while stream is not None and (left := pause_until - time.monotonic()) > 0:
                event = stream.next(left)
                if event is not None and on_event is not None:
                    on_event(event)
            if stream is None:
                time.sleep(max(0.0, pause_until - time.monotonic()))
        raise DaemonError(f"the daemon did not finish within {timeout_s:g} s (state "
                          f"{status.state}); see `micam session status`")


def _reachable(endpoint: str, control: str) -> str:
    """`endpoint` with a wildcard host replaced by the host of the control endpoint."""
    transport, _, rest = endpoint.partition("://")
    host, _, port = rest.rpartition(":")
    if transport == "tcp" and host in ("0.0.0.0", "*", "[::]", "::"):
        control_host = control.partition("://")[2].rpartition(":")[0]
        return f"tcp://{control_host}:{port}"
    return endpoint


def client_from_args(args: argparse.Namespace) -> DaemonClient:
    """A client for the options of `micam.commands.client_options.add_client_arguments`."""
    return DaemonClient(args.control, args.events, args.timeout,
                        Path(args.server_key) if args.server_key else None,
                        Path(args.client_key) if args.client_key else None)
