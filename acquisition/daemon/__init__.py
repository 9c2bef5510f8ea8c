"""The acquisition daemon: capture sessions driven over ZeroMQ (see docs/protocol.md).

`micam daemon` runs `run_daemon`; the operator's commands use `DaemonClient`. Modules:
config (pydantic settings), states (the state
machine), server (sockets), security and endpoints (CURVE, what is local), run (one open
session and its quality gate), quality (checks), hardware (what the daemon drives), service (the
loop), handlers (its requests), systemd, translog (transitions in the session), client (for the
commands; their options are micam.commands.client_options, their display micam.display). The
names below are imported on first use, so that `micam --help` stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "ConfigError": "config",
    "DaemonConfig": "config",
    "load_config": "config",
    "DaemonClient": "client",
    "DaemonError": "client",
    "State": "states",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
