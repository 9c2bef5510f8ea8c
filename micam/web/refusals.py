"""The page's refusals: a status, a code and one line for a person, as JSON.

Every refusal, whichever layer makes it (the Host check, the body limits, a route), is
`{"ok": false, "code": CODE, "error": WHY}` with a 4xx status (503 when the daemon cannot be
reached), so the page's script shows the reason and a program can branch on the code. A
refused WebSocket gets the same as its HTTP answer where the server can send one (uvicorn's
`websocket.http.response` extension), else a close code of 4000 + status.
"""

from __future__ import annotations

from starlette.responses import JSONResponse
from starlette.types import Receive, Scope, Send

MAX_SHOWN = 60
"""Characters of a request's own text quoted back in a reason."""


def refusal(status: int, code: str, message: str, close: bool = False) -> JSONResponse:
    """The JSON answer for a refused request; `close` ends the connection after it (a body
    still arriving is not waited for)."""
    headers = {"connection": "close"} if close else None
    return JSONResponse({"ok": False, "code": code, "error": message}, status_code=status,
                        headers=headers)


async def refuse(scope: Scope, receive: Receive, send: Send, status: int, code: str,
                 message: str, close: bool = False) -> None:
    """Send `refusal(...)` for an HTTP request or a WebSocket not yet accepted."""
    if scope["type"] == "websocket" and "websocket.http.response" not in scope.get(
            "extensions", {}):
        await send({"type": "websocket.close", "code": 4000 + status,
                    "reason": f"{code}: refused"})
        return
    await refusal(status, code, message, close)(scope, receive, send)


def shown(text: str) -> str:
    """`text` from a request, quoted for a reason: escaped, and cut to MAX_SHOWN characters."""
    return ascii(text[:MAX_SHOWN]) + ("..." if len(text) > MAX_SHOWN else "")
