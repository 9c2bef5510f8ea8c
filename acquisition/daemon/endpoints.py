"""ZeroMQ endpoints: the defaults, and which endpoints only this machine can reach."""

from __future__ import annotations

import ipaddress

DEFAULT_CONTROL = "tcp://127.0.0.1:5560"
DEFAULT_EVENTS = "tcp://127.0.0.1:5561"


def is_local_endpoint(endpoint: str) -> bool:
    """True for ipc://, inproc:// and tcp:// on a loopback address (127.0.0.0/8, ::1, localhost).

    Anything else ("*", 0.0.0.0, an interface or host name, another transport) may be reachable
    from the network.
    """
    transport, sep, rest = endpoint.partition("://")
    if not sep:
        return False
    if transport in ("ipc", "inproc"):
        return True
    if transport != "tcp":
        return False
    host = rest.rsplit(":", 1)[0].split(";")[-1].strip("[]")  # "source;host:port" binds too
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


_OFFSETS = {"jobs": 2, "files": 3}


def beside(control: str, role: str) -> str:
    """The default endpoint of the worker socket `role` ("jobs" or "files") of a daemon whose
    control socket is `control`: tcp port + 2 / + 3 (5562 and 5563 by default), or the ipc
    path with "-jobs" / "-files" appended. Two daemons on one machine thus never collide."""
    transport, _, rest = control.partition("://")
    if transport == "tcp":
        host, _, port = rest.rpartition(":")
        if port.isdigit():
            return f"tcp://{host}:{int(port) + _OFFSETS[role]}"
    return f"{control}-{role}"
