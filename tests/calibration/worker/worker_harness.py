"""`micam worker` with a hold point, for the end-to-end tests.

The first worker to take a final job while the file $HOLD_TOKEN exists removes the file (so
exactly one worker holds), tells the test on the datagram socket $NOTIFY_SOCKET
("HOLDING=<name>") and then waits, bounded, inside the job: the test kills it there, in the
middle of the job, with no race. Every other job runs as usual.
"""

from __future__ import annotations

import os
import socket
import sys
import threading
from pathlib import Path

import calibration.worker.worker as worker_module
from micam.cli import main

HOLD_S = 120.0
_compute = worker_module.compute


def _holding(job, session, joint, on_stage, memo=None):
    token = Path(os.environ["HOLD_TOKEN"])
    if job.kind == "final":
        try:
            token.unlink()
        except FileNotFoundError:
            pass
        else:
            on_stage("holding")
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
                s.sendto(f"HOLDING={sys.argv[sys.argv.index('--name') + 1]}".encode(),
                         os.environ["NOTIFY_SOCKET"])
            threading.Event().wait(HOLD_S)
    return _compute(job, session, joint, on_stage, memo)


worker_module.compute = _holding

if __name__ == "__main__":
    sys.exit(main(["worker", *sys.argv[1:]]))
