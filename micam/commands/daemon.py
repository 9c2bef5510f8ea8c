"""`micam daemon`: run the acquisition daemon (foreground; systemd runs it as a service)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "daemon", help="run the acquisition daemon (ZeroMQ control of captures)",
        description="Serve capture sessions over ZeroMQ (docs/protocol.md). Without a "
                    "[hardware] section in the config it runs on the simulated world.")
    p.add_argument("--config", type=Path, metavar="FILE",
                   help="TOML configuration (MICAM_DAEMON_* environment variables override it)")
    p.add_argument("--check", action="store_true",
                   help="validate the configuration and exit")
    p.add_argument("--schemas", type=Path, metavar="DIR",
                   help="write the protocol's JSON Schemas into DIR and exit")
    p.add_argument("--make-keys", type=Path, metavar="DIR",
                   help="create CURVE key pairs for the daemon and one client in DIR and exit")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.protocol import json_schemas
    from micam.daemon import check_config, run_daemon
    from micam.hardware import load_daemon_config
    from acquisition.contracts.keys import make_keys

    if args.schemas is not None:
        args.schemas.mkdir(parents=True, exist_ok=True)
        for name, schema in json_schemas().items():
            (args.schemas / f"{name}.schema.json").write_text(json.dumps(schema, indent=2) + "\n")
        print(f"JSON Schemas written to {args.schemas}")
        return 0
    if args.make_keys is not None:
        for path in make_keys(args.make_keys):
            print(path)
        return 0
    if args.check:
        print(check_config(load_daemon_config(args.config)))
        return 0
    return run_daemon(args.config, args.log_level)
