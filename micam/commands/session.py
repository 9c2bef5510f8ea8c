"""`micam session start|stop|pause|resume|abort|status`: run a capture session on the daemon."""

from __future__ import annotations

import argparse
import json

from .client_options import add_client_arguments
from .bounded import LONG_WAIT, integer


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("session", help="start, stop, pause, resume, abort a capture session",
                       description="Control the daemon's capture session.")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    start = actions.add_parser("start", help="open a new session (or continue an interrupted "
                                             "one with --resume)")
    start.add_argument("--poses", type=integer(1, 10_000),
                       help="rig poses to capture (default: the daemon's configuration)")
    start.add_argument("--resume", metavar="ID",
                       help="continue the interrupted session ID ('last': the newest one)")
    for name, text in (("stop", "end after the current step, as complete (references needed)"),
                       ("abort", "end after the current burst, as aborted"),
                       ("pause", "hold before the next step"),
                       ("resume", "continue a paused session")):
        action = actions.add_parser(name, help=text)
        if name in ("stop", "abort"):
            action.add_argument("--no-wait", action="store_true",
                                help="return at once instead of waiting for the session to "
                                     "close")
            action.add_argument("--wait-timeout", type=LONG_WAIT, default=120.0, metavar="S",
                                help="longest wait for the session to close (default 120 s)")
    status = actions.add_parser("status", help="what the daemon is doing")
    status.add_argument("--json", action="store_true", help="print the status reply as JSON")
    for action in actions.choices.values():
        add_client_arguments(action)
        action.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.daemon.client import client_from_args
    from micam.display import format_status

    with client_from_args(args) as client:
        if args.action == "status":
            status = client.status()
            print(json.dumps(status.model_dump(mode="json"), indent=2) if args.json
                  else format_status(status))
            return 0
        if args.action == "start":
            result = client.request("session.start", poses=args.poses, resume=args.resume)
            session = result["session"]
            verb = "resumed" if result["resumed"] else "started"
            print(f"session {session['id']} {verb}: {session['steps_done']}/"
                  f"{session['steps_total']} steps done; sessions are under {session['path']}")
            print(format_status(client.status()))
            return 0
        command = f"session.{args.action}"
        closing = client.status().session if args.action in ("stop", "abort") else None
        client.request(command)  # (an abort may close the session before any status after it)
        if closing is not None and not args.no_wait:
            client.wait_until(lambda s: s.session is None, args.wait_timeout)
            print(f"session {closing.id} closed ({args.action})")
            return 0
        print(format_status(client.status()))
    return 0
