"""`micam batch SESSION... --out DIR`: calibrate many sessions as tasks on a Dask cluster.

Registered by micam/cli.py beside the commands of micam/commands/ (it lives here, with the
batch it drives, because micam.batch uses `micam calibrate`'s options and code: a command
module importing micam.batch would make a cycle of the two packages).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition.contracts.errors import UserError

from ..commands.bounded import integer
from ..commands.calibrate import add_calibration_options, calibration_options

DEFAULT_WORKERS = 2


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "batch", help="calibrate many sessions as tasks on a Dask cluster",
        description="Calibrate every SESSION as `micam calibrate SESSION --out "
                    "DIR/NAME/result.json` would, each as a task on Dask's distributed "
                    "scheduler (a local cluster by default, --scheduler for an existing "
                    "one), and write the table of the batch, DIR/batch.csv and batch.json: "
                    "status, mean error against the session's truth.json, run time, why it "
                    "failed. Run it again to finish an interrupted batch: the sessions "
                    "calibrated with the same options are kept. Exit status 1 when a "
                    "session failed.")
    p.add_argument("sessions", type=Path, nargs="+", metavar="SESSION",
                   help="session directories (every worker must see them at these paths)")
    p.add_argument("--out", type=Path, required=True,
                   help="directory of the batch: a directory per session (result.json, "
                        "cell.json) and the table")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://HOST:8786 (`dask "
                        "scheduler`, then `dask worker ADDRESS` on each machine; default: "
                        "a local cluster of --workers processes)")
    p.add_argument("--workers", type=integer(1, 256), default=None,
                   help=f"worker processes of the local cluster, one thread each (default "
                        f"{DEFAULT_WORKERS})")
    p.add_argument("--retries", type=integer(0, 10), default=2,
                   help="retries of a task after a bug or its worker's death (default 2)")
    p.add_argument("--reports", action="store_true",
                   help="also write each session's report (result-report/), as micam "
                        "calibrate does; about 3 s more per session")
    p.add_argument("--restart", action="store_true",
                   help="recompute every session (default: keep those an earlier run "
                        "finished with the same options)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bar; print only the outcome")
    add_calibration_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from .runner import run_calibrations

    if args.scheduler is not None and args.workers is not None:
        raise UserError("--workers is for the local cluster; an existing cluster (--scheduler) "
                        "has the workers started on it with `dask worker`")
    options = {name: getattr(args, name) for name in calibration_options()}
    outcome = run_calibrations(args.sessions, args.out, options, scheduler=args.scheduler,
                               workers=args.workers or DEFAULT_WORKERS, retries=args.retries,
                               reports=args.reports, restart=args.restart,
                               progress=not args.quiet)
    ok = [r for r in outcome.rows if r.status == "ok"]
    kept = sum(r.kept for r in ok)
    print(f"batch: {len(outcome.rows)} sessions: {len(ok)} ok ({kept} kept from an earlier "
          f"run), {len(outcome.failed)} failed")
    for row in outcome.failed:
        print(f"  {row.session}: {row.status}: {row.message}")
    print(f"table: {outcome.csv}, {outcome.json}")
    return 1 if outcome.failed else 0
