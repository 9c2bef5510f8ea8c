"""The daemon's sockets: a control socket answering every request, a PUB event socket.

Every request gets exactly one reply, whatever it holds: a malformed, oversized, unknown or
refused request gets an error reply and the daemon carries on. The reply is serialised inside
the same guard as the answer, so even a reply that cannot be encoded (a lone UTF-16 surrogate
somewhere in it) is replaced by an error reply.

The control socket is a ROUTER that speaks REQ's envelope itself (the peer's identity, the
routing frames up to an empty delimiter, the request), not a REP: a REP socket keeps a state
machine that a failed send, or a peer speaking raw bytes (read as ZMTP 1.0 frames), can leave
sending replies to nobody, so that the daemon goes deaf. A ROUTER reads and writes whole
messages and has no such state; a REQ or a DEALER client works with it unchanged.

Every socket gets its inbound size limit (`ZMQ_MAXMSGSIZE`, per frame) and both its queue
lengths, in and out, before `bind`: ZeroMQ copies the options into each listener at bind time,
so a limit set after bind never applies. A frame above the socket's hard limit makes ZeroMQ
drop the connection before the daemon sees (or buffers) it; on the control socket a request
between `max_message_bytes` and the hard limit gets a clear `too_large` reply.

The outbound queues are what a peer that stops reading costs the daemon: each connection holds
at most its socket's `outbound` messages (ZeroMQ's default, 1000, let a stalled `samples`
subscriber hold 1000 blocks of the time data, 300 MB). A PUB socket drops what a full queue
cannot take, a ROUTER refuses it (`zmq.Again`, logged). The time data shares the event socket:
subscriptions are filtered at the publisher, so a subscriber's queue holds only the topics it
asked for, and a flood of `samples` never displaces the events of a subscriber that did not
ask for them (docs/protocol.md, Sockets).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from typing import Any

import zmq
from pydantic import BaseModel, ValidationError

from .config import ConfigError, SocketsConfig
from .local_access import bind_local
from acquisition.contracts.protocol import (
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

SUBSCRIPTION_LIMIT = 1024  # bytes: the largest frame a PUB socket accepts (a subscription)
SUBSCRIPTION_QUEUE = 16  # subscriptions queued per subscriber (x SUBSCRIPTION_LIMIT)
EVENTS_QUEUE = 8
"""Messages queued per subscriber of the event socket. The largest is a `samples` block
(`acquisition.live.mode.BLOCK_SAMPLES` rows x the columns x 2 bytes: 299 KB for 73 columns),
so a subscriber that stops reading holds at most 8 of them (2.3 MiB, plus the one being
written) in the daemon; the ones after are dropped for it, as PUB does for slow subscribers."""
MAX_TURNS = 1000  # busy turns of one `serve` call before the loop gets control back
MAX_ROUTING_FRAMES = 8  # REQ sends none (just the delimiter); a proxy chain adds one each
CONTROL_QUEUE = 16  # requests queued per control connection (x the hard limit: its memory bound)
REPLY_QUEUE = 4
"""Replies queued per control connection (a REQ client has one in flight; x the largest reply,
a `session.file` of `session_files.MAX_FILE_BYTES` in base64, 5.6 MB, is its memory bound)."""
UNENCODABLE_REPLY = (b'{"v": 2, "id": "", "ok": false, "result": null, "error": {"code": '
                     b'"internal", "message": "the reply could not be encoded"}}')
"""The reply of last resort, when not even an error reply can be encoded (never seen)."""


def control_hard_limit(max_message_bytes: int) -> int:
    """The control socket's `ZMQ_MAXMSGSIZE`, bytes: requests up to 16 x `max_message_bytes`
    (1 MiB by default) get a `too_large` reply; longer frames are dropped by ZeroMQ."""
    return min(16 * max_message_bytes, 16 * 2**20)


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
    except RecursionError:
        raise Refusal("bad_request", "the request is nested too deeply to be a request") from None
    except ValueError as exc:  # not UTF-8, not JSON, an integer of thousands of digits
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
    return value if isinstance(value, str) and len(value) <= 64 and _encodable(value) else ""


def _encodable(text: str) -> bool:
    """Whether `text` can go into a UTF-8 reply (JSON admits lone surrogates; UTF-8 does not)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def encode_reply(reply: Reply) -> bytes:
    """`reply` as one JSON frame; if it cannot be encoded, an `internal` error reply instead."""
    try:
        return reply.model_dump_json().encode()
    except Exception as exc:  # PydanticSerializationError, a bug in a result
        log.exception("cannot encode a reply; answering with an error instead")
        why = str(exc).encode("ascii", "backslashreplace").decode()
        fallback = Reply(id=reply.id if _encodable(reply.id) else "", ok=False, error=ErrorInfo(
            code="internal", message=f"internal error: the reply could not be encoded: {why}"))
    try:
        return fallback.model_dump_json().encode()
    except Exception:
        return UNENCODABLE_REPLY


class ControlServer:
    """Binds the control and event sockets; answers requests with `handler`; publishes events."""

    def __init__(self, sockets: SocketsConfig,
                 handler: Callable[[Request], BaseModel | dict[str, Any]]) -> None:
        check_exposure(sockets)
        self._handler = handler
        self._limit = sockets.max_message_bytes
        self._ipc_mode = sockets.ipc_mode
        self._context = zmq.Context()
        self._curve: CurveServer | None = None
        self._seq = -1
        try:
            if sockets.curve is not None:
                self._curve = CurveServer(self._context, sockets.curve)
            self._control = self.bind(zmq.ROUTER, sockets.control,
                                      control_hard_limit(sockets.max_message_bytes),
                                      CONTROL_QUEUE, REPLY_QUEUE)
            self._control.router_mandatory = 1  # a vanished client is an error we can log
            # A PUB socket receives only subscriptions (a flag byte and a topic).
            self._pub = self.bind(zmq.PUB, sockets.events, SUBSCRIPTION_LIMIT,
                                  SUBSCRIPTION_QUEUE, EVENTS_QUEUE)
        except BaseException:
            self.close()
            raise
        self._poller = zmq.Poller()
        self._poller.register(self._control, zmq.POLLIN)
        self._watched: dict[zmq.Socket, Callable[[], None]] = {}

    def bind(self, kind: int, endpoint: str, max_frame_bytes: int, inbound: int,
             outbound: int) -> zmq.Socket:
        """A socket of this server's context, CURVE-secured when configured, refusing inbound
        frames above `max_frame_bytes` and queueing at most `inbound` received and `outbound`
        unsent messages per connection (all set before bind, see the module docstring),
        bound to `endpoint` (an ipc socket file with the configured mode; ConfigError if
        binding fails). The caller closes it before `close`."""
        sock = self._context.socket(kind)
        sock.linger = 0
        sock.maxmsgsize = max_frame_bytes
        sock.rcvhwm = inbound
        sock.sndhwm = outbound
        if self._curve is not None:
            self._curve.secure(sock)
        try:
            bind_local(sock, endpoint, self._ipc_mode)
        except zmq.ZMQError as exc:
            sock.close()
            raise ConfigError(f"cannot bind {endpoint}: {exc}; is another daemon running, or "
                              "is the address mistyped?") from None
        except BaseException:
            sock.close()
            raise
        return sock

    @property
    def events_endpoint(self) -> str:
        return str(self._pub.getsockopt_string(zmq.LAST_ENDPOINT))

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
            if self._control in ready:
                self._reply_to(self._control.recv_multipart())
            for sock, on_readable in self._watched.items():
                if sock in ready:
                    on_readable()
            timeout_ms = 0

    def _reply_to(self, message: list[bytes]) -> None:
        """Answer one received request: exactly one reply to its sender, whatever went wrong."""
        identity, *rest = message
        delimiter = rest.index(b"") + 1 if b"" in rest else 0  # a DEALER may send none
        envelope, frames = rest[:delimiter], rest[delimiter:]
        if len(envelope) > MAX_ROUTING_FRAMES:
            log.warning("dropped a request with %d routing frames", len(envelope))
            return
        try:
            payload = encode_reply(self._answer(frames))
        except Exception:  # _answer guards itself; this is the last line of defence
            log.exception("internal error while answering a request")
            payload = UNENCODABLE_REPLY
        try:
            self._control.send_multipart([identity, *envelope, payload], zmq.NOBLOCK)
        except zmq.ZMQError as exc:  # the client went away, or does not read its replies
            log.info("cannot send a reply: %s", exc)

    def _answer(self, frames: list[bytes]) -> Reply:
        request_id = _request_id(frames)
        try:
            request = parse_request(frames, self._limit)
            result = self._handler(request)
            if isinstance(result, BaseModel):
                result = result.model_dump(mode="json")
            return Reply(id=request.id, ok=True, result=result)
        except Refusal as refusal:
            log.info("refused a request: %s", refusal.message)
            return Reply(id=request_id, ok=False,
                         error=ErrorInfo(code=refusal.code, message=refusal.message))
        except Exception as exc:  # a bug: answer, log it, keep serving
            log.exception("internal error while answering a request")
            return Reply(id=request_id, ok=False, error=ErrorInfo(
                code="internal", message=f"internal error: {type(exc).__name__}: {exc}"))

    def publish(self, event_type: type[BaseModel], **fields: Any) -> BaseModel:
        """Send an event of `event_type` (seq and time filled in); return it."""
        self._seq += 1
        event = event_type(seq=self._seq, time_utc=utc_now(), **fields)
        topic = event_type.model_fields["type"].default
        self._pub.send_multipart([topic.encode(), event.model_dump_json().encode()])
        return event

    def publish_frames(self, topic: str, frames: list[bytes | memoryview]) -> None:
        """Send a message of raw frames after its topic (live mode's time data; dropped
        by ZeroMQ for subscribers that did not ask for the topic or do not keep up)."""
        self._pub.send_multipart([topic.encode(), *frames], copy=False)

    def close(self) -> None:
        for name in ("_control", "_pub"):
            sock = getattr(self, name, None)
            if sock is not None:
                sock.close(linger=0)
        if self._curve is not None:
            self._curve.stop()
        self._context.term()
