"""Cut work over scan points into cache-sized blocks and run the blocks on threads.

Beamforming a block of points touches (block, M) steering vectors and products: 1024 points
of 72 microphones are 0.6 MB in complex64, which stays in a core's L2 cache while every
frequency bin is processed, instead of streaming the whole grid's 6 MB through memory per bin.
numpy's matrix products and element-wise operations release the GIL, so blocks run in
parallel on threads; BLAS itself is kept on one thread meanwhile (one level of parallelism,
and no OpenBLAS thread spinning for a descheduled partner on a loaded machine, see
`calibration._blas`).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from .._blas import single_threaded_blas

BLOCK_POINTS = 1024
"""Scan points per block (see the module docstring)."""


def default_workers() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def resolve_workers(workers: int | None) -> int:
    """`workers`, or all cores for None; at least 1."""
    if workers is None:
        return default_workers()
    if workers < 1:
        raise ValueError(f"workers {workers} must be at least 1 (or None for all cores)")
    return int(workers)


def point_blocks(n_points: int, size: int = BLOCK_POINTS) -> list[tuple[int, int]]:
    """(start, stop) of consecutive blocks of at most `size` points covering n_points."""
    return [(start, min(start + size, n_points)) for start in range(0, n_points, size)]


def run_tasks(tasks: list[Callable[[], None]], workers: int | None = None) -> None:
    """Run the tasks on up to `workers` threads (None: all cores), BLAS on one thread. Tasks
    must write disjoint outputs. An exception in any task is raised here."""
    n_threads = min(resolve_workers(workers), len(tasks))
    with single_threaded_blas():
        if n_threads <= 1:
            for task in tasks:
                task()
            return
        with ThreadPoolExecutor(n_threads, thread_name_prefix="micam-imaging") as pool:
            for future in [pool.submit(task) for task in tasks]:
                future.result()


def run_blocks(work: Callable[[int, int], None], n_points: int, workers: int | None = None,
               size: int = BLOCK_POINTS) -> None:
    """Call work(start, stop) for every block of points (see `run_tasks`)."""
    blocks = point_blocks(n_points, size)
    run_tasks([functools.partial(work, start, stop) for start, stop in blocks], workers)
