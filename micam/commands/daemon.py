"""`micam daemon`: run the acquisition daemon (foreground; systemd runs it as a service)."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "daemon", help="run the acquisition daemon (ZeroMQ control of captures)",
        description="Serve capture sessions over ZeroMQ (docs/protocol.md). Without a "
                    "[hardware] section in the config it runs on the simulated world.")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="TOML configuration (MICAM_DAEMON_* environment variables override it)")
    bring_up = p.add_mutually_exclusive_group()
    bring_up.add_argument("--boards", type=_labels, metavar="SERIAL,...",
                          help="bring up only these boards of the configuration (serials, or "
                               "audio interfaces' labels): previews and the cameras work, a "
                               "capture is refused (config key only_boards)")
    bring_up.add_argument("--cameras-only", dest="boards", action="store_const", const=(),
                          help="bring up the cameras alone, no board (only_boards = [])")
    p.add_argument("--check", action="store_true",
                   help="validate the configuration and exit")
    p.add_argument("--schemas", type=Path, metavar="DIR",
                   help="write the protocol's JSON Schemas into DIR and exit")
    p.add_argument("--make-keys", type=Path, metavar="DIR",
                   help="create CURVE key pairs for the daemon and one client in DIR and exit")
    p.set_defaults(run=run)


def _labels(text: str) -> tuple[str, ...]:
    """`--boards S1,S2`: the serials or labels, in the order given."""
    labels = tuple(label.strip() for label in text.split(",") if label.strip())
    if not labels:
        raise argparse.ArgumentTypeError("name at least one board, or use --cameras-only")
    return labels


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.protocol import json_schemas
    from micam.daemon import check_config, run_daemon
    from micam.hardware import load_daemon_config
    from micam.schemas import write_schemas
    from acquisition.contracts.keys import make_keys

    if args.schemas is not None:
        write_schemas(args.schemas, json_schemas())
        print(f"JSON Schemas written to {args.schemas}")
        return 0
    if args.make_keys is not None:
        for path in make_keys(args.make_keys):
            print(path)
        return 0
    if args.check:
        print(check_config(load_daemon_config(args.config)))
        return 0
    return run_daemon(args.config, args.log_level, args.boards)
