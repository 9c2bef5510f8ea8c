"""`micam capture` (the set-up is ready: capture the current step) and `micam redo`."""

from __future__ import annotations

import argparse

from .client_options import add_client_arguments
from .bounded import LONG_WAIT


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "capture", help="capture the current step (pose, reference) now",
        description="Tell the daemon that the set-up it asked for is ready, then show the "
                    "step's levels and checks until it completes or is abandoned.")
    p.add_argument("--no-wait", action="store_true", help="return as soon as it is accepted")
    p.add_argument("--wait-timeout", type=LONG_WAIT, default=300.0, metavar="S",
                   help="longest wait for the capture to finish (default 300 s)")
    p.add_argument("--quiet", action="store_true",
                   help="print only the outcome: one line, the step and complete or abandoned")
    add_client_arguments(p)
    p.set_defaults(run=run_capture)
    r = sub.add_parser(
        "redo", help="throw away the step being captured and capture it again",
        description="Abandon the step being captured after its current burst (the rig moved, "
                    "someone spoke...); the daemon then waits for `micam capture` again.")
    add_client_arguments(r)
    r.set_defaults(run=run_redo)


def run_capture(args: argparse.Namespace) -> int:
    from acquisition.daemon.client import client_from_args
    from micam.display import format_event, format_status
    from acquisition.contracts.protocol import CaptureResult

    with client_from_args(args) as client:
        stream = None if args.no_wait or args.quiet else client.subscribe()
        try:
            accepted = CaptureResult.model_validate(client.request("capture"))
            if args.no_wait:
                print(f"capturing {accepted.step} (capture {accepted.number})")
                return 0
            if not args.quiet:
                print(f"capturing {accepted.step} (capture {accepted.number})")
            status = client.wait_until(
                lambda s: (s.session is None or (s.last_capture is not None
                                                 and s.last_capture.number >= accepted.number)),
                args.wait_timeout, on_event=lambda e: print(format_event(e)), stream=stream)
        finally:
            if stream is not None:
                stream.close()
    last = status.last_capture
    if status.session is None:
        print("the session closed")
        return 0
    if args.quiet:
        print(f"{last.step} {last.outcome}" if last is not None else "no capture finished")
    else:
        print(format_status(status))
    return 0 if last is not None and last.outcome == "complete" else 3


def run_redo(args: argparse.Namespace) -> int:
    from acquisition.daemon.client import client_from_args

    with client_from_args(args) as client:
        result = client.request("redo")
    print(f"{result['step']} will be abandoned after the current burst; set up again and "
          "`micam capture`")
    return 0
