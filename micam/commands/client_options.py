"""The options of every `micam` command that talks to the daemon (light: no heavy imports)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from acquisition.daemon.endpoints import default_control

from .bounded import REPLY_TIMEOUT


ENDPOINT_FORMS = ("tcp://HOST:PORT", "ipc://PATH")


def endpoint(text: str) -> str:
    """An option's ZeroMQ endpoint, checked before anything connects (argparse's error else)."""
    scheme, sep, rest = text.partition("://")
    if not sep or scheme not in ("tcp", "ipc") or not rest:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a daemon endpoint; write {' or '.join(ENDPOINT_FORMS)}")
    if scheme == "tcp":
        host, colon, port = rest.rpartition(":")
        if not colon or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a daemon endpoint; a tcp one is tcp://HOST:PORT")
    return text


def add_control_argument(parser: argparse.ArgumentParser, what: str) -> None:
    """--control ENDPOINT, the one name of the daemon's endpoint in every command; --connect,
    its old spelling in `micam worker`, is accepted as a hidden alias."""
    control = default_control()
    parser.add_argument("--control", type=endpoint,
                        default=os.environ.get("MICAM_CONTROL", control), metavar="ENDPOINT",
                        help=f"the daemon's control socket{what} (default $MICAM_CONTROL or "
                             f"{control})")
    parser.add_argument("--connect", dest="control", type=endpoint, default=argparse.SUPPRESS,
                        help=argparse.SUPPRESS)


def add_client_arguments(parser: argparse.ArgumentParser) -> None:
    """--control, --events, --timeout and the CURVE keys, with environment defaults."""
    env = os.environ.get
    add_control_argument(parser, "")
    parser.add_argument("--events", type=endpoint, default=env("MICAM_EVENTS"), metavar="ENDPOINT",
                        help="the daemon's event socket (default: as the daemon reports)")
    parser.add_argument("--timeout", type=REPLY_TIMEOUT, default=5.0, metavar="S",
                        help="seconds to wait for each reply (default 5)")
    parser.add_argument("--server-key", type=Path, default=env("MICAM_SERVER_KEY"),
                        help="CURVE: the daemon's public certificate (server.key)")
    parser.add_argument("--client-key", type=Path, default=env("MICAM_CLIENT_KEY"),
                        help="CURVE: your secret certificate (client.key_secret)")
