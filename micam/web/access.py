"""Who may open the operator's page.

- By default the page listens on loopback (127.0.0.1) only: every account of this machine may
  open it, as every account may reach loopback TCP. Give a token on a shared machine.
- Any other address needs a token (`--token-file FILE`, or `MICAM_WEB_TOKEN`): a page that
  drives captures is never open to a network. The browser presents it once in the address
  (`/?token=...`), gets it back as an HttpOnly, SameSite=Strict cookie, and is sent to the
  address without it; programs may send `Authorization: Bearer TOKEN` instead.
- Every request must name this page in `Host`, and come from the page itself when it says
  where it comes from (`Origin`): hosts.py, against DNS rebinding and other sites' pages.
- TLS: put a reverse proxy in front (docs/operator.md); the page itself speaks plain HTTP.
"""

from __future__ import annotations

import hmac
import ipaddress
import os
import re
import stat
from pathlib import Path

from acquisition.contracts.errors import UserError

TOKEN_ENV = "MICAM_WEB_TOKEN"
COOKIE = "micam_token"
MIN_TOKEN_CHARS = 16
TOKEN_RE = re.compile(rf"[A-Za-z0-9._~-]{{{MIN_TOKEN_CHARS},512}}")
"""A token: characters that go unchanged into an address and a cookie."""


def is_loopback(host: str) -> bool:
    """True for localhost and the loopback addresses (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def read_token(path: Path | None) -> str | None:
    """The token from `path` (private to its owner, like a secret key) or from $MICAM_WEB_TOKEN;
    None when neither is given. UserError if it is unusable."""
    if path is None:
        token = os.environ.get(TOKEN_ENV)
        where = f"${TOKEN_ENV}"
    else:
        try:
            mode = stat.S_IMODE(os.stat(path).st_mode)
            token = path.read_text().strip()
        except OSError as exc:
            raise UserError(f"cannot read the token file {path}: {exc}") from None
        if mode & 0o077:
            raise UserError(f"the token file {path} may be read by other users (mode "
                            f"{mode:04o}); make it private with `chmod 600 {path}`")
        where = str(path)
    if token is None:
        return None
    if TOKEN_RE.fullmatch(token) is None:
        raise UserError(f"the token in {where} must be at least {MIN_TOKEN_CHARS} letters, "
                        "digits or ._~- (it goes into an address and a cookie); make one "
                        "with `python3 -c 'import secrets; print(secrets.token_urlsafe(24))'`")
    return token


def check_listen(host: str, token: str | None) -> None:
    """Refuse to listen off loopback without a token."""
    if token is None and not is_loopback(host):
        raise UserError(f"refusing to serve the page on {host} without a token: anyone who "
                        "reaches it could drive captures. Give --token-file FILE (or "
                        f"${TOKEN_ENV}), or listen on 127.0.0.1 and put a reverse proxy in "
                        "front (docs/operator.md)")


def token_matches(token: str | None, presented: str | None) -> bool:
    """Whether `presented` is the page's token (any request passes when there is none)."""
    if token is None:
        return True
    return presented is not None and hmac.compare_digest(token.encode(), presented.encode())
