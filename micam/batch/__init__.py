"""Batch calibrations on Dask: many sessions calibrated as `micam calibrate` would, as tasks.

`run_batch(sessions, out, calibrate_options)` is the Python API (for notebooks and scripts);
`micam batch` (`command`) its command line. Each session becomes a cell, `OUT/NAME/` with its
result.json; the batch writes a table of them (batch.csv, batch.json). See docs/batch.md.
"""

from .cells import BatchRow
from .runner import BatchOutcome, run_batch

__all__ = ["BatchOutcome", "BatchRow", "run_batch"]
