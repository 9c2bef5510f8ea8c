"""The batch table: a row per session, as batch.csv (for a spreadsheet) and batch.json.

batch.json is `{"options": {...}, "rows": [...]}`: the calibration options the batch ran with
and the rows (`BatchRow`), in the order the sessions were given; batch.csv has the same rows,
the mean error in millimetres and the run time in seconds. Both are written atomically.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path

from .cells import BatchRow

CSV_NAME = "batch.csv"
JSON_NAME = "batch.json"
COLUMNS = tuple(BatchRow.model_fields)


def write_table(rows: Sequence[BatchRow], options: Mapping[str, object], out: Path
                ) -> tuple[Path, Path]:
    """Write `out`/batch.csv and `out`/batch.json; returns their paths."""
    text = io.StringIO()
    writer = csv.DictWriter(text, COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if v is None else v for k, v in row.model_dump().items()})
    document = {"options": dict(options), "rows": [row.model_dump() for row in rows]}
    for path, data in ((out / CSV_NAME, text.getvalue()),
                       (out / JSON_NAME, json.dumps(document, indent=1) + "\n")):
        _write(path, data.encode())
    return out / CSV_NAME, out / JSON_NAME


def _write(path: Path, data: bytes) -> None:
    from acquisition.contracts.session import write_atomic  # here: `micam --help` stays light

    write_atomic(path, lambda fh: fh.write(data), replace=True)
