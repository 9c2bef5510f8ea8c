"""The options of every `micam` command that talks to the daemon (light: no heavy imports)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from .endpoints import default_control


def add_client_arguments(parser: argparse.ArgumentParser) -> None:
    """--control, --events, --timeout and the CURVE keys, with environment defaults."""
    env = os.environ.get
    control = default_control()
    parser.add_argument("--control", default=env("MICAM_CONTROL", control),
                        metavar="ENDPOINT",
                        help=f"the daemon's control socket (default $MICAM_CONTROL or {control})")
    parser.add_argument("--events", default=env("MICAM_EVENTS"), metavar="ENDPOINT",
                        help="the daemon's event socket (default: as the daemon reports)")
    parser.add_argument("--timeout", type=float, default=5.0, metavar="S",
                        help="seconds to wait for each reply (default 5)")
    parser.add_argument("--server-key", type=Path, default=env("MICAM_SERVER_KEY"),
                        help="CURVE: the daemon's public certificate (server.key)")
    parser.add_argument("--client-key", type=Path, default=env("MICAM_CLIENT_KEY"),
                        help="CURVE: your secret certificate (client.key_secret)")
