"""`micam watch`: a live view of the daemon in the terminal (progress, levels, warnings, and
the live calibration: uncertainty, predicted accuracy, where the next pose would help)."""

from __future__ import annotations

import argparse
import sys
import time

from .client_options import add_client_arguments
from .bounded import LONG_WAIT, TARGET_MM, integer


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("watch", help="follow the daemon's progress, levels and warnings live",
                       description="Print the daemon's status, then one line per event "
                                   "until interrupted (Ctrl-C).")
    p.add_argument("--count", type=integer(1, 10**9), metavar="N", help="stop after N events")
    p.add_argument("--duration", type=LONG_WAIT, metavar="S", help="stop after S seconds")
    p.add_argument("--json", action="store_true",
                   help="print JSON lines only: the status first, then one event per line "
                        "(notes such as missed events go to stderr)")
    p.add_argument("--target-mm", type=TARGET_MM, metavar="MM",
                   help="say when the live calibration predicts this mean microphone accuracy")
    add_client_arguments(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.daemon.client import client_from_args
    from micam.display import format_event, format_live, format_status
    from acquisition.contracts.protocol import LiveCalibrationEvent, StateEvent
    from acquisition.daemon.states import SESSION_STATES, State

    open_states = {s.value for s in SESSION_STATES - {State.STOPPING}}

    deadline = time.monotonic() + args.duration if args.duration is not None else None
    with client_from_args(args) as client:
        stream = client.subscribe()
        try:
            status = client.status()
            print(status.model_dump_json() if args.json else format_status(status), flush=True)
            note = sys.stderr if args.json else sys.stdout
            seen = 0
            last_seq = None
            open_session = status.session.id if status.session is not None else None
            while args.count is None or seen < args.count:
                wait = 1.0 if deadline is None else deadline - time.monotonic()
                if wait <= 0:
                    break
                event = stream.next(min(wait, 1.0))
                if event is None:
                    continue
                if last_seq is not None and event.seq <= last_seq:
                    print("(the daemon restarted: its event numbers start again)",
                          file=note, flush=True)
                elif last_seq is not None and event.seq != last_seq + 1:
                    print(f"(missed {event.seq - last_seq - 1} events)", file=note, flush=True)
                last_seq = event.seq
                seen += 1
                if isinstance(event, StateEvent):
                    open_session = event.session_id if event.state in open_states else None
                if args.json:
                    line = event.model_dump_json()
                elif isinstance(event, LiveCalibrationEvent) and args.target_mm is not None:
                    # "you may stop" only while its session is open (a worker may answer late)
                    is_open = event.session_id is not None and event.session_id == open_session
                    line = format_live(event.update, args.target_mm / 1e3 if is_open else None)
                else:
                    line = format_event(event)
                print(line, flush=True)
        finally:
            stream.close()
    return 0
