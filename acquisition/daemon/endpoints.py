"""ZeroMQ endpoints: the defaults, and which endpoints only this machine can reach.

By default the daemon listens on ipc sockets in its runtime directory (see
`default_runtime_dir`), which it creates with mode 0750: only its own user and group can reach
them (docs/security.md). This module is light (no zmq) because every `micam` command imports it.
"""

from __future__ import annotations

import ipaddress
import os
from pathlib import Path

RUNTIME_DIR_ENV = "MICAM_RUNTIME_DIR"


def default_runtime_dir() -> Path:
    """Where the daemon's ipc sockets go by default: $MICAM_RUNTIME_DIR, else
    $XDG_RUNTIME_DIR/micam (a user's daemon), else /tmp/micam-<uid>. The systemd unit sets
    MICAM_RUNTIME_DIR=/run/micam for the service and the users of its group."""
    explicit = os.environ.get(RUNTIME_DIR_ENV)
    if explicit:
        return Path(explicit)
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    if xdg:
        return Path(xdg) / "micam"
    return Path("/tmp") / f"micam-{os.getuid()}"


def default_control() -> str:
    return f"ipc://{default_runtime_dir()}/control"


def default_events() -> str:
    return f"ipc://{default_runtime_dir()}/events"


def ipc_path(endpoint: str) -> Path | None:
    """The socket file of an `ipc://PATH` endpoint; None for other transports and for
    abstract sockets (`ipc://@name`), which have no file."""
    transport, sep, rest = endpoint.partition("://")
    if not sep or transport != "ipc" or rest.startswith("@"):
        return None
    return Path(rest)


def is_abstract_ipc(endpoint: str) -> bool:
    """`ipc://@name`: a Linux abstract socket, which any local user can connect to (no file,
    so no permissions)."""
    return endpoint.startswith("ipc://@")


def is_tcp(endpoint: str) -> bool:
    return endpoint.startswith("tcp://")


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
