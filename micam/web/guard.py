"""The page's gate: every request's `Host`, `Origin` and token, and the security headers.

An ASGI middleware in front of every route and the WebSocket, in every mode (with or without a
token, on loopback or not):

1. `Host`: exactly one, a host name or address with an optional port, and one of the names the
   page serves (hosts.py). A request without one, or with a malformed or doubled one, gets 400
   (HTTP/1.1 requires exactly one); a well-formed name the page does not serve gets 421
   Misdirected Request: the request reached a server that does not answer for that name,
   which is what a DNS-rebinding page's requests are (403 would say "you may not", when the
   truth is "not here").
2. `Origin`, when there is one (a browser sends it with every POST and WebSocket, and with
   cross-site reads): the same host and port as `Host`, http or https; anything else (another
   site, `null`) gets 403, so another site's page cannot drive or read the page.
3. The token, when the page has one (access.py): cookie, `Authorization: Bearer`, or
   `?token=` on the page's address (answered by a redirect that sets the cookie); 401
   otherwise.

A WebSocket anywhere but at WEBSOCKET_PATH gets 404. Every answer, refusals included,
carries SECURITY_HEADERS.
"""

from __future__ import annotations

from urllib.parse import parse_qs

from starlette.responses import Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .access import COOKIE, token_matches
from .hosts import ServedHosts, format_authority, parse_authority, parse_origin, same_origin
from .refusals import refuse, shown

SECURITY_HEADERS = [
    (b"content-security-policy", b"default-src 'self'; img-src 'self' data:; "
                                 b"connect-src 'self'; frame-ancestors 'none'"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"cache-control", b"no-store"),
]
WEBSOCKET_PATH = "/ws"
"""The page's one WebSocket: one elsewhere is refused here (the routes would close it without
a word)."""
RESPONSE_STARTS = {"http.response.start", "websocket.http.response.start"}


class AccessGuard:
    """See the module docstring. `served`: the names the page answers to; `token`: the page's
    token, or None."""

    def __init__(self, app: ASGIApp, token: str | None, served: ServedHosts) -> None:
        self.app = app
        self.token = token
        self.served = served

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] in RESPONSE_STARTS:
                message = {**message, "headers": [*message.get("headers", []),
                                                  *SECURITY_HEADERS]}
            await send(message)

        headers: dict[str, list[str]] = {}
        for key, value in scope["headers"]:
            headers.setdefault(key.decode("latin-1").lower(), []).append(value.decode("latin-1"))
        problem = self._problem(scope, headers)
        if problem is not None:
            await refuse(scope, receive, send_with_headers, *problem)
            return
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        given = query.get("token", [None])[0]
        if self.token is not None and given is not None and scope["type"] == "http" and (
                scope["path"] == "/"):
            if token_matches(self.token, given):  # the address with the token: set the cookie
                await Response(status_code=303, headers={
                    "location": "/", "set-cookie": f"{COOKIE}={given}; HttpOnly; "
                                                   "SameSite=Strict; Path=/"})(
                    scope, receive, send_with_headers)
                return
        presented = (_cookie(headers.get("cookie", []), COOKIE)
                     or _bearer(headers.get("authorization", [""])[0]) or given)
        if not token_matches(self.token, presented):
            await refuse(scope, receive, send_with_headers, 401, "token_needed",
                         "this page needs its token: open it as /?token=TOKEN "
                         "(docs/operator.md)")
            return
        await self.app(scope, receive, send_with_headers)

    def _problem(self, scope: Scope, headers: dict[str, list[str]]
                 ) -> tuple[int, str, str] | None:
        """Why the request's `Host`, `Origin` or address is refused (status, code, reason), or
        None."""
        hosts = headers.get("host", [])
        if len(hosts) != 1:
            return 400, "bad_host", (f"refused: the request has {len(hosts)} Host headers; "
                                     "it needs exactly one")
        host = parse_authority(hosts[0])
        if host is None:
            return 400, "bad_host", (f"refused: the Host header {shown(hosts[0])} is not a "
                                     "host name or address with an optional port")
        if not self.served.serves(host):
            return 421, "misdirected", (
                f"refused: this page does not answer to the host {format_authority(host)} "
                f"(a page of another site pointed at this address?); it answers to "
                f"{self.served.names()}; add a name with --allow-host NAME[:PORT]")
        origins = headers.get("origin", [])
        if len(origins) > 1:
            return 400, "bad_origin", "refused: the request has more than one Origin header"
        if origins:
            origin = parse_origin(origins[0])
            if origin is None or not same_origin(origin, host):
                return 403, "other_site", (f"refused: the request comes from "
                                           f"{shown(origins[0])}, another site than this page")
        if not scope.get("query_string", b"").isascii():
            return 400, "bad_request", ("refused: the address holds bytes that are not ASCII "
                                        "(percent-encode them)")
        if scope["type"] == "websocket" and scope["path"] != WEBSOCKET_PATH:
            return 404, "not_found", (f"there is no WebSocket at {shown(scope['path'])}; the "
                                      f"page's is {WEBSOCKET_PATH}")
        return None


def _cookie(headers: list[str], name: str) -> str | None:
    for header in headers:
        for part in header.split(";"):
            key, _, value = part.strip().partition("=")
            if key == name:
                return value
    return None


def _bearer(header: str) -> str | None:
    scheme, _, value = header.partition(" ")
    return value.strip() if scheme.lower() == "bearer" and value else None
