"""The page served by uvicorn, with every connection bounded in size and in time.

- A request's head (request line and headers) is at most MAX_HEAD_BYTES (h11's limit; a
  longer one gets 400) and must arrive within the request timeout of the connection's start,
  or of the previous answer on a kept-alive connection: HeadDeadlineProtocol, since uvicorn
  times out only an idle kept-alive connection, and a client that sends a byte now and then
  restarts even that. A late head gets 408 and the connection is closed.
- A body is bounded by limits.BodyLimit (size and the same timeout); a body the page did not
  read (it answered first) is drained for at most the timeout, then the connection is closed.
- At most MAX_CONNECTIONS connections and requests at once (uvicorn answers 503 beyond);
  an idle kept-alive connection is closed after KEEP_ALIVE_S.
- A WebSocket message from a browser is at most MAX_WS_MESSAGE_BYTES (the page sends none).
"""

from __future__ import annotations

import asyncio
from typing import ClassVar

import h11
import uvicorn
from starlette.types import ASGIApp
from uvicorn.protocols.http.h11_impl import H11Protocol

MAX_HEAD_BYTES = 16 * 1024
MAX_CONNECTIONS = 128
KEEP_ALIVE_S = 5
MAX_WS_MESSAGE_BYTES = 64 * 1024
LATE_HEAD = (b"HTTP/1.1 408 Request Timeout\r\ncontent-type: application/json\r\n"
             b"connection: close\r\ncontent-length: %d\r\n\r\n%s")


class HeadDeadlineProtocol(H11Protocol):
    """uvicorn's HTTP/1.1 protocol with a deadline for each request's head: armed when the
    connection opens and after each answer, disarmed when a head is complete (a request
    starts) or the connection becomes a WebSocket."""

    timeout_s: ClassVar[float]
    """Seconds for a head (set by `serve`: `--request-timeout`)."""
    _deadline: asyncio.TimerHandle | None = None
    _armed_at: object = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._disarm_if_started()

    def on_response_complete(self) -> None:
        self._arm()
        super().on_response_complete()
        self._disarm_if_started()  # a pipelined request may have started already

    def handle_websocket_upgrade(self, event: h11.Request) -> None:
        self._disarm()
        super().handle_websocket_upgrade(event)

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def _arm(self) -> None:
        self._disarm()
        self._armed_at = self.cycle
        self._deadline = self.loop.call_later(self.timeout_s, self._expire)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _disarm_if_started(self) -> None:
        if self.cycle is not self._armed_at:
            self._disarm()

    def _expire(self) -> None:
        self._deadline = None
        if self.transport.is_closing():
            return
        if self.conn.their_state is h11.IDLE:  # between requests: a late (or no) head
            body = (b'{"ok": false, "code": "too_slow", "error": "the request\'s head did not '
                    b'arrive within %g s"}' % self.timeout_s)
            self.transport.write(LATE_HEAD % (len(body), body))
        self.transport.close()


WS_PROTOCOL = "websockets-sansio"
"""uvicorn's WebSocket implementation on the websockets package's Sans-I/O core (its legacy
one, "websockets", warns that it is deprecated on every start)."""


def serve(app: ASGIApp, host: str, port: int, request_timeout_s: float) -> None:
    """Serve `app` on `host`:`port` until SIGINT or SIGTERM (see the module docstring)."""
    protocol = type("HeadDeadlineProtocol", (HeadDeadlineProtocol,),
                    {"timeout_s": request_timeout_s})
    uvicorn.run(app, host=host, port=port, log_level="warning", ws=WS_PROTOCOL,
                lifespan="on", http=protocol, h11_max_incomplete_event_size=MAX_HEAD_BYTES,
                limit_concurrency=MAX_CONNECTIONS, timeout_keep_alive=KEEP_ALIVE_S,
                ws_max_size=MAX_WS_MESSAGE_BYTES)
