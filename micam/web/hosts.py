"""Which names the page answers to: the `Host` and `Origin` checks against DNS rebinding.

A page of another site can make its own name resolve to 127.0.0.1 (DNS rebinding): the
browser then sends that page's requests to this page, with the other site's name in `Host`
and in `Origin`, and lets its script read the answers. So every request (GET, POST and the
WebSocket alike, with or without a token) must name in `Host` a name this page serves:

- the loopback names `localhost`, `127.x.y.z` and `[::1]`, with the port the page listens on;
- the address it is bound to (`--listen`), with that port; bound to every address (`0.0.0.0`,
  `[::]`), any IP address with that port: an address, unlike a name, cannot be rebound (the
  browser connected to exactly that address);
- the names the operator adds (`--allow-host NAME[:PORT]`, e.g. a reverse proxy's name; without
  a port, any port).

A `Host` without a port stands for the scheme's default port (80 or 443). Names compare without
regard to case; IPv6 addresses in their compressed form. `X-Forwarded-Host` is ignored: a proxy
passes the name in `Host` (docs/operator.md). A request's `Origin`, when it has one, must name
the same scheme-less host and port as its `Host` (the same-origin rule), hence a served name.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass
from urllib.parse import urlsplit

from acquisition.contracts.errors import UserError
from .access import is_loopback

Authority = tuple[str, int | None]
"""A host (lower case; an IPv6 address without brackets, compressed) and its port, if given."""

DEFAULT_PORTS = {"http": 80, "https": 443}
MAX_AUTHORITY = 300
_LABEL = r"[a-z0-9](?:[a-z0-9-]{0,61}[a-z0-9])?"
_NAME_RE = re.compile(rf"{_LABEL}(?:\.{_LABEL})*")
_PORT_RE = re.compile(r"[0-9]{1,5}")
_WILDCARDS = {"0.0.0.0", "::"}


class HostError(UserError):
    """An `--allow-host` that is not a host name or address with an optional port."""


def parse_authority(text: str) -> Authority | None:
    """`text` ("name", "name:port", "1.2.3.4:port", "[::1]:port") as an Authority; None if it
    is none of these (a user part, a path, a bad name, a port above 65535)."""
    if len(text) > MAX_AUTHORITY:
        return None
    text = text.lower()
    if text.startswith("["):
        inside, bracket, rest = text[1:].partition("]")
        try:
            host = ipaddress.IPv6Address(inside).compressed
        except ValueError:
            return None
        if not bracket:
            return None
    else:
        host, colon, port = text.partition(":")
        rest = colon + port
        if _NAME_RE.fullmatch(host) is None:
            return None
    if not rest:
        return host, None
    port = rest[1:]
    if rest[0] != ":" or _PORT_RE.fullmatch(port) is None or not 0 < int(port) < 65536:
        return None
    return host, int(port)


def format_authority(authority: Authority) -> str:
    """How `authority` is written in a `Host` header."""
    host, port = authority
    shown = f"[{host}]" if ":" in host else host
    return shown if port is None else f"{shown}:{port}"


def parse_allowed(text: str) -> Authority:
    """An `--allow-host NAME[:PORT]` argument; HostError if it is not one."""
    authority = parse_authority(text.strip())
    if authority is None:
        raise HostError(f"--allow-host {text}: give a host name or address with an optional "
                        "port, e.g. rig-pc.example or rig-pc.example:443 or [fd00::5]:8765")
    return authority


def _is_address(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def _port_matches(wanted: int | None, given: int | None) -> bool:
    """Whether a `Host` port `given` names port `wanted` (None: any); no port stands for a
    default port."""
    if wanted is None:
        return True
    return wanted in DEFAULT_PORTS.values() if given is None else given == wanted


@dataclass(frozen=True)
class ServedHosts:
    """The names a page listening on `bound`:`port` answers to (see the module docstring)."""

    port: int
    bound: str
    allowed: tuple[Authority, ...] = ()

    def serves(self, authority: Authority) -> bool:
        host, port = authority
        if is_loopback(host) or host == self._bound() or (
                self._bound() in _WILDCARDS and _is_address(host)):
            return _port_matches(self.port, port)
        return any(host == name and _port_matches(wanted, port)
                   for name, wanted in self.allowed)

    def _bound(self) -> str:
        bound = self.bound.strip("[]").lower()
        try:
            return ipaddress.ip_address(bound).compressed
        except ValueError:
            return bound

    def names(self) -> str:
        """The served names, for a person."""
        names = [f"localhost:{self.port}", f"127.0.0.1:{self.port}", f"[::1]:{self.port}"]
        bound = self._bound()
        if bound in _WILDCARDS:
            names.append(f"any address:{self.port}")
        elif not is_loopback(bound):
            names.append(format_authority((bound, self.port)))
        names += [format_authority(a) if a[1] is not None else f"{a[0]} (any port)"
                  for a in self.allowed]
        return ", ".join(names)


def parse_origin(origin: str) -> tuple[str, Authority] | None:
    """The scheme, and the host and port (the scheme's default filled in), an `Origin` header
    names; None if it is not an http(s) origin (`null`, another scheme, a path, a user)."""
    try:
        parts = urlsplit(origin)
    except ValueError:
        return None
    if (parts.scheme not in DEFAULT_PORTS or parts.path or parts.query or parts.fragment
            or "@" in parts.netloc):
        return None
    authority = parse_authority(parts.netloc)
    if authority is None:
        return None
    return parts.scheme, (authority[0], authority[1] or DEFAULT_PORTS[parts.scheme])


def same_origin(origin: tuple[str, Authority], host: Authority) -> bool:
    """Whether `origin` (from parse_origin) names the page at `host` (a `Host` without a port
    stands for the origin's default port)."""
    scheme, (origin_host, origin_port) = origin
    return origin_host == host[0] and origin_port == (host[1] or DEFAULT_PORTS[scheme])
