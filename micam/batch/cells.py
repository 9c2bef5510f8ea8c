"""One cell of a batch: a session, its directory of outputs, and the task that calibrates it.

A cell's directory (`OUT/NAME/`) holds what `micam calibrate` writes for its session
(result.json, and report/ with `reports`) and `cell.json`, the cell's row of the batch table
with the calibration options it was made with. The task (`run_cell`) is what a Dask worker
runs: it reads the session where it is (a path every worker sees), calibrates it through
`micam.calibrating.calibrate_session` (the code of `micam calibrate`), and returns the row.
Bad input fails the cell alone (status "failed", the `UserError`'s message); anything else
raises, so that Dask retries it, and is a bug.

A cell is finished when its cell.json says "ok" for the same options and its result.json is a
valid result of that session: a resumed batch keeps it (`finished_row`) and recomputes the rest.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, ValidationError

from acquisition.contracts.bounded_files import (
    MAX_DOCUMENT_BYTES,
    UnreadableFile,
    read_bounded_text,
)
from acquisition.contracts.errors import UserError

from ..calibrating import calibrate_session, default_report_dir

RESULT_NAME = "result.json"
CELL_NAME = "cell.json"
TRACEBACK_NAME = "traceback.txt"
"""Where a cell that hit a bug in micam keeps its traceback."""
MAX_CELL_BYTES = 1 << 20
"""The largest cell.json a resumed batch reads (a row and the options: a few hundred bytes)."""

Status = Literal["ok", "failed", "error"]
"""ok: calibrated; failed: bad input (the session or an option, `message` says which); error:
a bug in micam or a task whose workers kept dying (`message` says which), after the retries."""


class BatchRow(BaseModel):
    """One row of the batch table (batch.csv, batch.json): a session and its calibration.

    Attributes:
        session: the session directory (absolute).
        cell: the cell's name, its directory under the batch's --out.
        status: see `Status`.
        mean_mic_error_mm: the mean microphone error against the session's truth.json, mm
            (None: no truth.json, or not calibrated).
        seconds: the task's run time on its worker, s (as recorded when it was computed).
        message: why it failed, or "" when ok.
        result: the result.json written (None: none).
        kept: True when a resumed batch kept the cell as an earlier run left it.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    session: str
    cell: str
    status: Status
    mean_mic_error_mm: float | None = None
    seconds: float = 0.0
    message: str = ""
    result: str | None = None
    kept: bool = False


class CellRecord(BaseModel):
    """cell.json: the row of a computed cell and the calibration options it was made with."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    options: dict[str, object]
    row: BatchRow


@dataclass(frozen=True)
class Cell:
    """A session of the batch (absolute path) and its name (its directory under `out`)."""

    session: Path
    name: str
    out: Path

    @property
    def directory(self) -> Path:
        return self.out / self.name

    @property
    def result(self) -> Path:
        return self.directory / RESULT_NAME


def plan_cells(sessions: Sequence[Path], out: Path) -> list[Cell]:
    """A cell per distinct session, in the order given, named after its directory; sessions
    whose directories share a name are named by their path below the sessions' common
    directory ("2024-01__s", "2024-02__s"), so that the same sessions always get the same
    names (and a resumed batch finds its cells)."""
    paths = list(dict.fromkeys(Path(os.path.abspath(s)) for s in sessions))
    base = [p.name for p in paths]
    common = Path(os.path.commonpath(paths)) if len(paths) > 1 else None
    names = []
    for path, name in zip(paths, base, strict=True):
        if base.count(name) > 1 and common is not None:
            name = "__".join(path.relative_to(common).parts)
        names.append(name)
    return [Cell(p, n, out) for p, n in zip(paths, names, strict=True)]


def portable_options(options: Mapping[str, object]) -> dict[str, object]:
    """The calibration options as JSON values, with their files (`prior`, `layout`, `intrinsics`)
    made absolute, so that a worker in another directory reads the same files and cell.json
    compares them exactly."""
    out: dict[str, object] = {}
    for key, value in options.items():
        if key in ("prior", "layout") and value is not None:
            value = os.path.abspath(str(value))
        elif key == "intrinsics":
            items = []
            for item in value or ():  # type: ignore[attr-defined]
                camera, sep, file = str(item).partition("=")
                items.append(f"{camera}={os.path.abspath(file)}" if sep and file else item)
            value = items
        out[key] = value
    return json.loads(json.dumps(out))


def finished_row(cell: Cell, options: Mapping[str, object]) -> BatchRow | None:
    """The row of `cell` if an earlier run finished it with these options (cell.json says ok,
    result.json is a valid result of the same session), marked `kept` (and naming the
    result where it is now: the batch's directory may have moved); else None."""
    from calibration.result import CalibrationResult

    try:
        record = CellRecord.model_validate_json(
            read_bounded_text(cell.directory / CELL_NAME, MAX_CELL_BYTES))
        result = CalibrationResult.model_validate_json(
            read_bounded_text(cell.result, MAX_DOCUMENT_BYTES))
    except (UnreadableFile, ValidationError, ValueError):
        return None
    if (record.options != dict(options) or record.row.status != "ok"
            or record.row.session != str(cell.session)
            or result.session_id != _session_id(cell.session)):
        return None
    return record.row.model_copy(update={"kept": True, "result": str(cell.result)})


def _session_id(session: Path) -> str | None:
    """The session's id from its journal (None: unreadable)."""
    from acquisition.contracts.session import SessionError, SessionReader

    try:
        return SessionReader(session).session_id
    except (SessionError, OSError, ValueError):
        return None


def run_cell(cell: Cell, options: Mapping[str, object], reports: bool = False) -> BatchRow:
    """Calibrate `cell`'s session as `micam calibrate SESSION --out DIR/result.json` with
    these options would (and write its report with `reports`), write cell.json, and return
    its row. A `UserError` makes a "failed" row naming the session; any other exception is
    raised (a bug: Dask retries the task, then reports it)."""
    from calibration.result import compare_with_truth

    start = time.perf_counter()
    clear_outputs(cell)
    cell.directory.mkdir(parents=True, exist_ok=True)
    args = argparse.Namespace(**options, session=cell.session, out=cell.result, report=None,
                              acoular_xml=None, acoular_calib=None, truth=None, force=False)
    try:
        done = calibrate_session(args, report=reports)
    except UserError as exc:
        message = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        row = BatchRow(session=str(cell.session), cell=cell.name, status="failed",
                       seconds=time.perf_counter() - start,
                       message=message or type(exc).__name__)
    else:
        error = (None if done.truth is None else
                 1e3 * compare_with_truth(done.run.result, done.truth)["mean_mic_error_m"])
        row = BatchRow(session=str(cell.session), cell=cell.name, status="ok",
                       mean_mic_error_mm=error, seconds=time.perf_counter() - start,
                       result=str(cell.result))
    write_record(cell, options, row)
    return row


def clear_outputs(cell: Cell) -> None:
    """Remove what an earlier run left in `cell`'s directory (cell.json first, so that a cell
    half cleared is never finished), and nothing else of it."""
    for name in (CELL_NAME, RESULT_NAME, TRACEBACK_NAME):
        (cell.directory / name).unlink(missing_ok=True)
    shutil.rmtree(default_report_dir(cell.result), ignore_errors=True)


def write_record(cell: Cell, options: Mapping[str, object], row: BatchRow) -> None:
    """Write `cell`'s cell.json atomically (after its result.json: a cell killed between the
    two is not finished)."""
    from acquisition.contracts.session import write_atomic

    data = CellRecord(options=dict(options), row=row).model_dump_json(indent=1).encode()
    cell.directory.mkdir(parents=True, exist_ok=True)
    write_atomic(cell.directory / CELL_NAME, lambda fh: fh.write(data), replace=True)
