"""Request bodies bounded as they arrive: in size, and in time.

An ASGI middleware in front of every HTTP route. Nothing a page sends is longer than a
command (a few hundred bytes), so every body is held to `max_bytes`:

- a `Content-Length` above it is answered 413 at once, before a byte of the body is read;
- a body without one (chunked) is counted as its pieces arrive, and answered 413 as soon as
  the count passes the limit; the route never sees more than `max_bytes`;
- the whole body must arrive within `timeout_s` of the request's head: a client that trickles
  it gets 408 and the connection is closed. (The head itself is bounded by the server:
  server.py.)

So a request costs the page at most `max_bytes` of body (plus the server's own buffer of
64 KiB per connection), however long it is or claims to be.
"""

from __future__ import annotations

import asyncio
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .refusals import refuse


class _TooLarge(Exception):
    """The body passed the limit (raised out of `receive`, caught by the middleware)."""


class _TooSlow(Exception):
    """The body did not arrive in time (raised out of `receive`, caught by the middleware)."""


class BodyLimit:
    """See the module docstring: bodies of at most `max_bytes`, within `timeout_s` seconds."""

    def __init__(self, app: ASGIApp, max_bytes: int, timeout_s: float) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        lengths = {v for k, v in scope["headers"] if k.lower() == b"content-length"}
        if len(lengths) > 1 or not all(v.isdigit() and len(v) <= 20 for v in lengths):
            await refuse(scope, receive, send, 400, "bad_request",
                         "the request's Content-Length is not one number of bytes")
            return
        if lengths and int(lengths.pop()) > self.max_bytes:
            await self._too_large(scope, receive, send)
            return
        deadline = asyncio.get_running_loop().time() + self.timeout_s
        state: dict[str, Any] = {"received": 0, "complete": False, "started": False}

        async def limited_receive() -> Message:
            if state["complete"]:  # the body is in: what follows is a disconnect, unbounded
                return await receive()
            try:
                async with asyncio.timeout_at(deadline):
                    message = await receive()
            except TimeoutError:
                raise _TooSlow() from None
            if message["type"] != "http.request":
                state["complete"] = True
                return message
            state["received"] += len(message.get("body", b""))
            if state["received"] > self.max_bytes:
                raise _TooLarge()
            state["complete"] = not message.get("more_body", False)
            return message

        async def watched_send(message: Message) -> None:
            state["started"] = True
            await send(message)

        try:
            await self.app(scope, limited_receive, watched_send)
        except _TooLarge:
            if not state["started"]:
                await self._too_large(scope, receive, send)
        except _TooSlow:
            if not state["started"]:
                await refuse(scope, receive, send, 408, "too_slow",
                             f"the request's body did not arrive within {self.timeout_s:g} s",
                             close=True)

    async def _too_large(self, scope: Scope, receive: Receive, send: Send) -> None:
        await refuse(scope, receive, send, 413, "too_large",
                     f"the request's body is longer than {self.max_bytes} bytes; nothing this "
                     "page takes is")
