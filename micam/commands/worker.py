"""`micam worker --control ENDPOINT`: calibrate the daemon's sessions as they are captured."""

from __future__ import annotations

import argparse
import os
import signal
from pathlib import Path
from types import FrameType

from acquisition.contracts.bounded_files import size_text
from acquisition.daemon.endpoints import beside

from .client_options import add_control_argument, endpoint
from .bounded import Bounded, integer, positive


def _size(text: str) -> int:
    """A size in bytes, with an optional unit (an input error if it is none)."""
    from calibration.worker.cache import parse_size

    return parse_size(text)


CACHE_MAX = Bounded(_size, "a size (e.g. 500MiB, 4GiB, 2GB)", 2**20, 2**50, show=size_text)
"""`--cache-max`: from 1 MiB to 1024 TiB."""


def register(sub: argparse._SubParsersAction) -> None:
    env = os.environ.get
    p = sub.add_parser(
        "worker", help="calibrate the daemon's poses and sessions (ZeroMQ worker)",
        description="Connect to a micam daemon, take its calibration jobs one at a time (a "
                    "live calibration after each pose, the full one when a session closes), "
                    "fetch the session files over ZeroMQ into a local cache, and send the "
                    "results back. Runs until SIGTERM or Ctrl-C.")
    add_control_argument(p, "; the jobs and file endpoints are beside it")
    p.add_argument("--jobs", type=endpoint, metavar="ENDPOINT",
                   help="the daemon's jobs endpoint, if not beside")
    p.add_argument("--files", type=endpoint, metavar="ENDPOINT",
                   help="the daemon's file endpoint, if not beside")
    p.add_argument("--name", help="this worker's name in the daemon's events (default host-pid)")
    p.add_argument("--cache", type=Path, default=Path("~/.cache/micam/worker"),
                   help="directory for fetched session files, one per worker "
                        "(default ~/.cache/micam/worker)")
    p.add_argument("--cache-max", type=CACHE_MAX, default="4GiB", metavar="SIZE",
                   help="size limit of the cache (e.g. 500MiB, 4GiB, 2GB); beyond it the least "
                        "recently used sessions are evicted, never the one a job is using "
                        "(default 4GiB)")
    p.add_argument("--heartbeat", type=positive(30, " s"), default=1.0, metavar="S",
                   help="heartbeat interval in seconds (default 1; match the daemon's)")
    p.add_argument("--daemon-timeout", type=positive(3600, " s"), default=10.0, metavar="S",
                   help="reconnect after this long without a word from the daemon (default 10)")
    p.add_argument("--no-joint", action="store_true",
                   help="final calibrations without the joint fit (faster, less accurate)")
    p.add_argument("--max-jobs", type=integer(1, 10**9), metavar="N", help="exit after N jobs")
    p.add_argument("--server-key", type=Path, default=env("MICAM_SERVER_KEY"),
                   help="CURVE: the daemon's public certificate (server.key)")
    p.add_argument("--client-key", type=Path, default=env("MICAM_CLIENT_KEY"),
                   help="CURVE: this worker's secret certificate (client.key_secret)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.daemon.systemd import configure_logging
    from acquisition.contracts.errors import UserError
    from calibration.worker import Worker, WorkerSettings

    if (args.server_key is None) != (args.client_key is None):
        raise UserError("CURVE needs both --server-key and --client-key")
    configure_logging(args.log_level)
    settings = WorkerSettings(
        jobs=args.jobs or beside(args.control, "jobs"),
        files=args.files or beside(args.control, "files"),
        cache=args.cache, cache_max_bytes=args.cache_max, heartbeat_interval_s=args.heartbeat,
        daemon_timeout_s=args.daemon_timeout, joint=not args.no_joint,
        server_key=args.server_key, client_key=args.client_key,
        **({"name": args.name} if args.name else {}))
    worker = Worker(settings)

    def on_signal(_signum: int, _frame: FrameType | None) -> None:
        worker.stop()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    worker.run(args.max_jobs)
    return 0
