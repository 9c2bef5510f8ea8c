"""`micam sessions`: the sessions the daemon holds, with their status and progress."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    from .client_options import add_client_arguments

    p = sub.add_parser("sessions", help="list the daemon's sessions",
                       description="List every session under the daemon's session root.")
    p.add_argument("--json", action="store_true", help="print the daemon's reply as JSON")
    add_client_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.daemon.client import client_from_args
    from acquisition.contracts.protocol import SessionsResult

    with client_from_args(args) as client:
        result = SessionsResult.model_validate(client.request("sessions.list"))
    if args.json:
        print(json.dumps(result.model_dump(mode="json"), indent=2))
        return 0
    print(f"sessions in {result.root}:")
    if not result.sessions:
        print("  none")
    for s in result.sessions:
        print(f"  {s.id:<32} {s.status:<12} {s.poses_done:>4}/{s.n_poses:<4} poses  "
              f"{s.steps_done}/{s.steps_total} steps  {s.created_utc:%Y-%m-%d %H:%M} UTC")
    for problem in result.problems:
        print(f"  unreadable: {problem}")
    return 0
