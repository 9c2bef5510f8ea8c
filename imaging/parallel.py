"""Cut work over scan points into cache-sized blocks and run the blocks on threads; run
independent jobs (CLEAN-SC bins) in worker processes.

Beamforming a block of points touches (block, M) steering vectors and products: 1024 points
of 72 microphones are 0.6 MB in complex64, which stays in a core's L2 cache while every
frequency bin is processed, instead of streaming the whole grid's 6 MB through memory per bin.
numpy's matrix products and element-wise operations release the GIL, so blocks run in
parallel on threads; BLAS itself is kept on one thread meanwhile (one level of parallelism,
and no OpenBLAS thread spinning for a descheduled partner on a loaded machine, see
`calibration._blas`).

CLEAN-SC is the opposite case: thousands of small array operations per bin, during which the
interpreter holds its global lock, so threads do not run them in parallel (measured: 1.2x on
two cores). Its bins, and the poses of a localization evaluation, are independent and small to
ship (CSMs or a session path, a steering model without its arrays, the results), so they go to
worker processes instead (`run_in_processes`).
"""

from __future__ import annotations

import functools
import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from calibration._blas import single_threaded_blas
from calibration._cores import resolve_workers

Mapper = Callable[[Callable[..., Any], list[tuple[Any, ...]]], Iterable[Any]]
"""Runs function(*job) for every job somewhere else, results in the jobs' order: a pool of
this machine's processes (`run_in_processes` with its `workers` bound), or tasks on a Dask
cluster (`micam.batch.cluster.ClusterMap`). The function and the jobs must pickle."""

BLOCK_POINTS = 1024
"""Scan points per block (see the module docstring)."""


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


_POOLS: dict[int, ProcessPoolExecutor] = {}


def process_pool(workers: int) -> ProcessPoolExecutor:
    """A pool of `workers` processes, created on first use and kept for the life of this
    process (starting one costs about a second; a warm one takes a job in milliseconds).

    The processes are forked from a clean server process (the "forkserver" method, "spawn"
    where it does not exist) that has the imaging code imported, never from the caller, which
    may hold threads and locks (a daemon's sockets, a BLAS pool); they inherit none of its
    state, so a job must carry its data.
    """
    pool = _POOLS.get(workers)
    if pool is None:
        methods = multiprocessing.get_all_start_methods()
        context = multiprocessing.get_context("forkserver" if "forkserver" in methods
                                              else "spawn")
        if context.get_start_method() == "forkserver":
            context.set_forkserver_preload(["imaging"])
        pool = _POOLS[workers] = ProcessPoolExecutor(workers, mp_context=context)
    return pool


def discard_pool(workers: int) -> None:
    """Forget (and shut down) the pool of `workers` processes, e.g. after one of them died."""
    pool = _POOLS.pop(workers, None)
    if pool is not None:
        pool.shutdown(wait=False, cancel_futures=True)


def run_in_processes(function: Callable[..., Any], jobs: list[tuple[Any, ...]],
                     workers: int) -> Iterator[Any]:
    """function(*job) for every job on the pool of `workers` processes, results in the jobs'
    order as they become available. `function` and the jobs' arguments must pickle.

    Raises:
        RuntimeError: a worker process died; the pool is discarded (a new one is made next
            time) and the message says what usually causes it.
    """
    pool = process_pool(workers)
    try:
        futures = [pool.submit(function, *job) for job in jobs]
        for future in futures:
            yield future.result()
    except BrokenProcessPool:
        discard_pool(workers)
        raise RuntimeError(
            "a micam worker process died (killed, out of memory, or the calling script runs "
            "its work at import: put it under `if __name__ == \"__main__\":`); run again, or "
            "with workers=1 to stay in this process") from None
