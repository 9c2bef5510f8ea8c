"""`micam web`: the operator's page (a web application talking to the daemon over ZeroMQ)."""

from __future__ import annotations

import argparse
from pathlib import Path

from .client_options import add_client_arguments
from .bounded import BAND_HZ, DEPTH_M, RANGE_DB, TARGET_MM, number, positive

DEFAULT_LISTEN = "127.0.0.1:8765"
DEFAULT_REQUEST_TIMEOUT_S = 10.0
REQUEST_TIMEOUT = number(0.1, 3600, " s")
"""`--request-timeout`: seconds a client has for a request's head, and again for its body."""


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
    p.add_argument("--allow-host", action="append", default=[], metavar="NAME[:PORT]",
                   help="a name the page answers to besides localhost, 127.0.0.1, [::1] and "
                        "the --listen address (each with its port), e.g. a reverse proxy's "
                        "name; without a port, any port. Repeatable. Requests naming another "
                        "host are refused (421), against DNS rebinding")
    p.add_argument("--request-timeout", type=REQUEST_TIMEOUT, default=DEFAULT_REQUEST_TIMEOUT_S,
                   metavar="S", help="seconds a client has to send a request's head, and again "
                                     f"its body (default {DEFAULT_REQUEST_TIMEOUT_S:g}); a "
                                     "slower one is cut off (408)")
    p.add_argument("--target-mm", type=TARGET_MM, default=0.5, metavar="MM",
                   help="the live calibration's predicted accuracy at which the page says "
                        "'enough poses' (default 0.5 mm)")
    live = p.add_argument_group("live acoustic view (while the daemon is in live mode)")
    live.add_argument("--geometry", type=Path, metavar="FILE",
                      help="calibration result.json: draw live acoustic maps over camera 0 "
                           "(without it the page shows no maps)")
    live.add_argument("--band", type=BAND_HZ, default=4000.0, metavar="HZ",
                      help="band centre (default 4000)")
    live.add_argument("--fraction", type=int, choices=(1, 3), default=3,
                      help="1: octave, 3: third octave (default)")
    live.add_argument("--depth", type=DEPTH_M, default=1.0, metavar="M",
                      help="the scan plane's distance in front of camera 0 (default 1 m)")
    live.add_argument("--clean-sc", action="store_true", help="deconvolve with CLEAN-SC")
    live.add_argument("--range-db", type=RANGE_DB, default=15.0, help="dynamic range (default 15)")
    live.add_argument("--live-fps", type=positive(60, " fps"), default=10.0,
                      help="maps per second drawn for the page (default 10)")
    add_client_arguments(p)
    p.set_defaults(run=run)


def _live_stream(args: argparse.Namespace):  # -> LiveStream | None
    """The page's live acoustic view of --geometry, or None."""
    if args.geometry is None:
        return None
    from acquisition.daemon.client import client_from_args
    from imaging import load_geometry
    from imaging.live import LiveSettings
    from micam.web.live_stream import LiveStream

    settings = LiveSettings(band_hz=args.band, fraction=args.fraction, depth_m=args.depth,
                            clean_sc=args.clean_sc, dynamic_range_db=args.range_db,
                            image_scale=0.5)
    geometry = load_geometry(args.geometry)
    geometry.camera(settings.camera)
    return LiveStream(lambda: client_from_args(args), geometry, settings, args.live_fps)


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.errors import UserError

    try:
        from micam.web.access import check_listen, read_token
        from micam.web.app import create_app
        from micam.web.bridge import Bridge
        from micam.web.hosts import ServedHosts, parse_allowed
        from micam.web.server import serve
    except ImportError as exc:
        raise UserError(f"`micam web` needs the web packages ({exc.name} is missing): "
                        "pip install 'micam[web]'") from None
    from acquisition.daemon.client import client_from_args

    host, _, port = args.listen.rpartition(":")
    host = host.strip("[]")
    if not host or not (port.isascii() and port.isdigit()) or not 0 < int(port) < 65536:
        raise UserError(f"--listen {args.listen}: give HOST:PORT with a port from 1 to 65535, "
                        f"e.g. {DEFAULT_LISTEN}")
    served = ServedHosts(int(port), host, tuple(parse_allowed(a) for a in args.allow_host))
    token = read_token(args.token_file)
    check_listen(host, token)
    client = client_from_args(args)
    try:
        bridge = Bridge(client, target_m=args.target_mm / 1e3, live_stream=_live_stream(args))
        app = create_app(bridge, token, served, args.request_timeout)
        print(f"micam web: the page is at http://{args.listen}/ (daemon {client.control})",
              flush=True)
        serve(app, host, int(port), args.request_timeout)
    finally:
        client.close()
    return 0
