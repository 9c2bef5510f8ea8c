"""Run a batch of calibrations as tasks on Dask's distributed scheduler.

Dask does the placement, the retries and the data movement: each session is one task
(`cells.run_cell`) submitted with `retries`, on a `LocalCluster` of worker processes (one
thread each: a calibration is single-threaded where it matters, and processes keep their
BLAS and OpenCV pools apart) or on an existing cluster (`scheduler`). A worker that dies (out
of memory, killed, its machine gone) loses its task to another worker, up to the scheduler's
`distributed.scheduler.allowed-failures` times (set to `retries` on the local cluster). The
cluster and the tasks are `cluster`'s, which the studies' cells run through too.

The sessions are read where they are: every worker must see the same paths (a shared file
system), as it must see `out`. The batch is resumable: a cell an earlier run finished with
the same options is kept (`cells.finished_row`), so a batch stopped at any point (Ctrl-C, a
lost scheduler) is run again with the same command.
"""

from __future__ import annotations

import sys
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from acquisition.contracts.errors import UserError

from ..outputs import check_output_dirs
from .cells import (
    TRACEBACK_NAME,
    BatchRow,
    Cell,
    finished_row,
    plan_cells,
    portable_options,
    run_cell,
    write_record,
)
from ..cluster import cluster, submit
from ..cluster import dashboard as cluster_dashboard
from .table import write_table

if TYPE_CHECKING:
    from distributed import Client, Future

MAX_SESSIONS = 100_000
"""The most sessions one batch takes."""


@dataclass(frozen=True)
class BatchOutcome:
    """The rows of a batch (in the order of its sessions), where its table was written, and
    the Dask dashboard's address when one was served (None: none)."""

    rows: list[BatchRow]
    csv: Path
    json: Path
    dashboard: str | None

    @property
    def failed(self) -> list[BatchRow]:
        return [r for r in self.rows if r.status != "ok"]


def run_batch(sessions: Sequence[Path], out: Path, calibrate_options: Sequence[str] = (), *,
              scheduler: str | None = None, workers: int = 2, retries: int = 2,
              reports: bool = False, restart: bool = False, progress: bool = True
              ) -> BatchOutcome:
    """Calibrate every session as `micam calibrate SESSION --out OUT/NAME/result.json
    CALIBRATE_OPTIONS` would, as Dask tasks, and write the table (the Python API of
    `micam batch`; `calibrate_options` as on its command line, e.g. ["--latency", "common"]).

    Args:
        sessions: session directories, each seen by every worker at this path.
        out: the batch's directory (made if missing): a directory per session and the table.
        scheduler: an existing scheduler's address (tcp://HOST:8786); None: a `LocalCluster`
            of `workers` processes on this machine, closed at the end.
        retries: a task's retries after a bug or its worker's death.
        reports: also write each session's report, as `micam calibrate` does.
        restart: recompute every session (default: keep those finished with these options).
        progress: show a progress bar and each failure on stderr.

    Raises:
        UserError: no sessions, an --out that cannot hold the batch, a bad calibrate
            option, a scheduler that cannot be reached. A session that cannot be calibrated
            is not an error here: its row says why.
    """
    from ..commands.calibrate import calibration_options

    return run_calibrations(sessions, out, calibration_options(calibrate_options),
                            scheduler=scheduler, workers=workers, retries=retries,
                            reports=reports, restart=restart, progress=progress)


def run_calibrations(sessions: Sequence[Path], out: Path, options: Mapping[str, object], *,
                     scheduler: str | None = None, workers: int = 2, retries: int = 2,
                     reports: bool = False, restart: bool = False, progress: bool = True
                     ) -> BatchOutcome:
    """`run_batch` with the calibration options already parsed (by name, as
    `micam.commands.calibrate.calibration_options` gives them)."""
    from tqdm import tqdm

    if not sessions:
        raise UserError("no session to calibrate; name at least one session directory")
    if len(sessions) > MAX_SESSIONS:
        raise UserError(f"{len(sessions)} sessions: a batch takes at most {MAX_SESSIONS}; "
                        "split it")
    check_output_dirs(("--out", out), reuse=True)
    out = Path(out).absolute()
    cells = plan_cells(sessions, out)
    _check_apart(cells)
    out.mkdir(parents=True, exist_ok=True)
    portable = portable_options(options)
    rows: dict[str, BatchRow] = {}
    if not restart:
        for cell in cells:
            kept = finished_row(cell, portable)
            if kept is not None:
                rows[cell.name] = kept
    todo = [c for c in cells if c.name not in rows]
    dashboard = None
    with tqdm(total=len(cells), initial=len(rows), desc="batch", unit="session",
              disable=not progress) as bar:
        def done(cell: Cell, row: BatchRow) -> None:
            rows[cell.name] = row
            bar.update()
            if row.status != "ok":
                bar.write(f"micam: batch: {cell.session}: {row.status}: {row.message}",
                          file=sys.stderr)

        if todo:
            with cluster(scheduler, workers, retries) as client:
                dashboard = cluster_dashboard(client)
                if dashboard and progress:
                    bar.write(f"micam: batch: Dask dashboard at {dashboard}", file=sys.stderr)
                _submit(client, todo, portable, reports, retries, done)
    ordered = [rows[c.name] for c in cells]
    csv_path, json_path = write_table(ordered, portable, out)
    return BatchOutcome(ordered, csv_path, json_path, dashboard)


def _check_apart(cells: Sequence[Cell]) -> None:
    """UserError when a cell's directory would fall in or over a session (an --out among
    the sessions), which the batch would then write into."""
    from acquisition.contracts.session import JOURNAL_NAME  # here: `micam --help` stays light

    sessions = [c.session for c in cells]
    for cell in cells:
        for session in sessions:
            if (cell.directory == session or session in cell.directory.parents
                    or cell.directory in session.parents
                    or (cell.directory / JOURNAL_NAME).exists()):
                raise UserError(f"--out {cell.out} would put the outputs of {cell.session} "
                                f"in or around the session {session}; choose an --out "
                                "outside the sessions' directories")


def _submit(client: Client, cells: Sequence[Cell], options: Mapping[str, object],
            reports: bool, retries: int, done: Callable[[Cell, BatchRow], None]) -> None:
    """Run `cells` as tasks (one each, `retries` retries) and hand each row to `done` as
    its task ends."""
    from distributed import as_completed

    futures = submit(client, run_cell, [(c,) for c in cells],
                     [f"calibrate-{c.name}" for c in cells], retries, options=options,
                     reports=reports)
    by_key = {f.key: c for f, c in zip(futures, cells, strict=True)}
    for future in as_completed(futures):
        cell = by_key[future.key]
        done(cell, _row(future, cell, options))


def _row(future: Future, cell: Cell, options: Mapping[str, object]) -> BatchRow:
    """The row a task returned, or an "error" row for a task that raised (a bug, after its
    retries) or whose workers kept dying; its cell.json records it."""
    from distributed.scheduler import KilledWorker

    from acquisition.contracts.session import write_atomic

    try:
        row = future.result()
    except KilledWorker:
        message = ("the workers running it died, each time (killed, or out of memory); the "
                   "scheduler gave up after distributed.scheduler.allowed-failures")
    except Exception as exc:  # a bug in micam, raised on the worker
        trace = cell.directory / TRACEBACK_NAME
        text = "".join(traceback.format_exception(type(exc), exc, future.traceback()))
        cell.directory.mkdir(parents=True, exist_ok=True)
        write_atomic(trace, lambda fh: fh.write(text.encode()), replace=True)
        first = str(exc).strip().splitlines()[:1]
        message = (f"a bug in micam: {type(exc).__name__}"
                   f"{': ' + first[0] if first else ''} (its traceback is in {trace}; "
                   "report it with that file)")
    else:
        return row
    row = BatchRow(session=str(cell.session), cell=cell.name, status="error", message=message)
    write_record(cell, options, row)
    return row
