"""The daemon's sockets: a REP control socket answering every request, a PUB event socket.

Every request gets exactly one reply, whatever it holds: a malformed, oversized, unknown or
refused request gets an error reply and the daemon carries on. A request above the hard
`MAXMSGSIZE` (16 MiB) is dropped by ZeroMQ itself before it reaches us; below that, the
configured `max_message_bytes` applies with a clear `too_large` reply.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from typing import Any

import zmq
from pydantic import BaseModel, ValidationError

from .config import ConfigError, SocketsConfig
from .protocol import (
    COMMANDS,
    PROTOCOL_VERSION,
    REQUEST_TYPES,
    Envelope,
    ErrorCode,
    ErrorInfo,
    Reply,
    Request,
    utc_now,
)
from .security import CurveServer, check_exposure

log = logging.getLogger("micam.daemon")

HARD_MESSAGE_LIMIT = 16 * 2**20
MAX_TURNS = 1000  # busy turns of one `serve` call before the loop gets control back


class Refusal(Exception):
    """A request the daemon answers with an error reply (code and a message for a person)."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


def _describe(exc: ValidationError) -> str:
    return "; ".join(f"{'.'.join(map(str, e['loc'])) or 'request'}: {e['msg']}"
                     for e in exc.errors())


def parse_request(frames: list[bytes], limit: int) -> Request:
    """Validate one received request; raise Refusal saying what is wrong with it."""
    if len(frames) != 1:
        raise Refusal("bad_request", f"a request is one frame of JSON; got {len(frames)} frames")
    raw = frames[0]
    if len(raw) > limit:
        raise Refusal("too_large", f"the request has {len(raw)} bytes; the limit is {limit}")
    try:
        data = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise Refusal("bad_request", f"the request is not UTF-8 JSON: {exc}") from None
    if not isinstance(data, dict):
        raise Refusal("bad_request", f"a request is a JSON object, not {type(data).__name__}")
    try:
        envelope = Envelope.model_validate(data)
    except ValidationError as exc:
        raise Refusal("bad_request", _describe(exc)) from None
    if envelope.v != PROTOCOL_VERSION:
        raise Refusal("unsupported_version",
                      f"protocol version {envelope.v} is not supported; this daemon speaks "
                      f"version {PROTOCOL_VERSION}")
    request_type = REQUEST_TYPES.get(envelope.command)
    if request_type is None:
        raise Refusal("unknown_command",
                      f"unknown command {envelope.command!r}; commands: {', '.join(COMMANDS)}")
    try:
        return request_type.model_validate(data)  # type: ignore[return-value]
    except ValidationError as exc:
        raise Refusal("bad_request", f"{envelope.command}: {_describe(exc)}") from None


def _request_id(frames: list[bytes]) -> str:
    """The id of a request for its error reply, if one can be read at all."""
    try:
        value = json.loads(frames[0]).get("id", "")
    except Exception:
        return ""
    return value if isinstance(value, str) and len(value) <= 64 else ""


class ControlServer:
    """Binds the control and event sockets; answers requests with `handler`; publishes events."""

    def __init__(self, sockets: SocketsConfig,
                 handler: Callable[[Request], BaseModel | dict[str, Any]]) -> None:
        check_exposure(sockets)
        self._handler = handler
        self._limit = sockets.max_message_bytes
        self._context = zmq.Context()
        self._curve: CurveServer | None = None
        self._seq = -1
        try:
            if sockets.curve is not None:
                self._curve = CurveServer(self._context, sockets.curve)
            self._rep = self.bind(zmq.REP, sockets.control)
            self._rep.maxmsgsize = HARD_MESSAGE_LIMIT
            self._pub = self.bind(zmq.PUB, sockets.events)
        except BaseException:
            self.close()
            raise
        self._poller = zmq.Poller()
        self._poller.register(self._rep, zmq.POLLIN)
        self._watched: dict[zmq.Socket, Callable[[], None]] = {}

    def bind(self, kind: int, endpoint: str) -> zmq.Socket:
        """A socket of this server's context, CURVE-secured when configured, bound to
        `endpoint` (ConfigError if that fails). The caller closes it before `close`."""
        sock = self._context.socket(kind)
        sock.linger = 0
        if self._curve is not None:
            self._curve.secure(sock)
        try:
            sock.bind(endpoint)
        except zmq.ZMQError as exc:
            sock.close()
            raise ConfigError(f"cannot bind {endpoint}: {exc}; is another daemon running, or "
                              "is the address mistyped?") from None
        return sock

    @property
    def events_endpoint(self) -> str:
        return self._pub.last_endpoint.decode()

    @property
    def last_event_seq(self) -> int:
        return self._seq

    def watch(self, sock: zmq.Socket, on_readable: Callable[[], None]) -> None:
        """Also wait on `sock` in `serve`, calling `on_readable` when it has messages."""
        self._poller.register(sock, zmq.POLLIN)
        self._watched[sock] = on_readable

    def serve(self, timeout_s: float) -> None:
        """Answer the requests waiting (and let watched sockets read theirs), or wait up to
        `timeout_s` for one. Bounded: after MAX_TURNS busy turns it returns to the loop."""
        timeout_ms = round(timeout_s * 1000)
        for _ in range(MAX_TURNS):
            ready = dict(self._poller.poll(timeout_ms))
            if not ready:
                return
            if self._rep in ready:
                frames = self._rep.recv_multipart()
                self._rep.send(self._answer(frames).model_dump_json().encode())
            for sock, on_readable in self._watched.items():
                if sock in ready:
                    on_readable()
            timeout_ms = 0

    def _answer(self, frames: list[bytes]) -> Reply:
        request_id = _request_id(frames)
        try:
            request = parse_request(frames, self._limit)
            result = self._handler(request)
        except Refusal as refusal:
            log.info("refused a request: %s", refusal.message)
            return Reply(id=request_id, ok=False,
                         error=ErrorInfo(code=refusal.code, message=refusal.message))
        except Exception as exc:  # a bug: answer, log it, keep serving
            log.exception("internal error while answering a request")
            return Reply(id=request_id, ok=False, error=ErrorInfo(
                code="internal", message=f"internal error: {type(exc).__name__}: {exc}"))
        if isinstance(result, BaseModel):
            result = result.model_dump(mode="json")
        return Reply(id=request.id, ok=True, result=result)

    def publish(self, event_type: type[BaseModel], **fields: Any) -> BaseModel:
        """Send an event of `event_type` (seq and time filled in); return it."""
        self._seq += 1
        event = event_type(seq=self._seq, time_utc=utc_now(), **fields)
        topic = event_type.model_fields["type"].default
        self._pub.send_multipart([topic.encode(), event.model_dump_json().encode()])
        return event

    def close(self) -> None:
        for name in ("_rep", "_pub"):
            sock = getattr(self, name, None)
            if sock is not None:
                sock.close(linger=0)
        if self._curve is not None:
            self._curve.stop()
        self._context.term()
