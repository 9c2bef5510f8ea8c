"""`micam`: the one command-line entry point, with a subcommand per job.

Each subcommand lives in its own module (`acquisition/commands/…`) and registers itself here;
heavy imports happen only when a subcommand runs, so `micam --help` is instant.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from .commands import (
    calibrate,
    capture,
    config,
    daemon,
    daq,
    evaluate_imaging,
    image,
    import_session,
    inspect,
    live,
    session,
    sessions,
    simulate,
    study,
    watch,
    web,
    worker,
)
from .errors import UserError

SUBCOMMANDS = (
    simulate, import_session, inspect, calibrate, study, image, evaluate_imaging, daq, daemon,
    config, session,
    capture, watch, sessions, web, live,
    worker,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="micam",
        description="Calibrate acoustic cameras and run their capture hardware.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in SUBCOMMANDS:
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `micam` command line; returns the process exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except KeyboardInterrupt:
        print("micam: interrupted", file=sys.stderr)
        return 130
    except UserError as exc:
        print(f"micam: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
