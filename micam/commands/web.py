"""`micam web`: the operator's page (a web application talking to the daemon over ZeroMQ)."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition.daemon.cli_args import add_client_arguments

DEFAULT_LISTEN = "127.0.0.1:8765"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "web", help="serve the operator's page: cameras, levels, live calibration, control",
        description="Serve a web page that shows and drives the daemon (docs/operator.md). It "
                    "listens on loopback unless given --listen and a token.")
    p.add_argument("--listen", default=DEFAULT_LISTEN, metavar="HOST:PORT",
                   help=f"address of the page (default {DEFAULT_LISTEN}; another host than "
                        "loopback needs --token-file)")
    p.add_argument("--token-file", type=Path, metavar="FILE",
                   help="a file (mode 0600) holding the token the page asks for (default "
                        "$MICAM_WEB_TOKEN; needed off loopback)")
    p.add_argument("--target-mm", type=float, default=0.5, metavar="MM",
                   help="the live calibration's predicted accuracy at which the page says "
                        "'enough poses' (default 0.5 mm)")
    add_client_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.errors import UserError

    try:
        import uvicorn

        from acquisition.web.access import check_listen, read_token
        from acquisition.web.app import create_app
        from acquisition.web.bridge import Bridge
    except ImportError as exc:
        raise UserError(f"`micam web` needs the web packages ({exc.name} is missing): "
                        "pip install 'micam[web]'") from None
    from acquisition.daemon.client import client_from_args

    host, _, port = args.listen.rpartition(":")
    if not host or not port.isdigit():
        raise UserError(f"--listen {args.listen}: give HOST:PORT, e.g. {DEFAULT_LISTEN}")
    token = read_token(args.token_file)
    check_listen(host.strip("[]"), token)
    client = client_from_args(args)
    try:
        bridge = Bridge(client, target_m=args.target_mm / 1e3)
        app = create_app(bridge, token)
        print(f"micam web: the page is at http://{args.listen}/ (daemon {client.control})",
              flush=True)
        uvicorn.run(app, host=host.strip("[]"), port=int(port), log_level="warning",
                    ws="websockets", lifespan="on")
    finally:
        client.close()
    return 0
