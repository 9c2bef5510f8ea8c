"""The Dask cluster a batch runs on, and independent jobs run on it in order (`ClusterMap`).

Every kind of batch cell goes through here: the calibrations of `micam batch` (`runner`),
the bands of `micam study`, the calibrations of `micam evaluate-imaging --folds`, the rows of
benchmarks/bench_real_lab.py. `cluster` opens the client (a `LocalCluster` of worker
processes, one thread each, or an existing scheduler) and says where its dashboard is;
`submit` makes one task per job, retried `retries` times; `ClusterMap` is the `Mapper` that
calibration/ takes (`imaging.parallel.Mapper`: function(*job) for every job,
results in the jobs' order), so a study runs its cells on the cluster without knowing Dask.

It is a module of micam/ itself, not of micam/batch/, so that the commands (micam/commands/)
use it without importing the batch, which imports them.

A job's function and arguments are pickled to the workers: they must import the same micam,
and see the same paths (sessions, outputs) as the machine that submits them.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import PurePath
from typing import TYPE_CHECKING, Any

from acquisition.contracts.errors import UserError

if TYPE_CHECKING:
    from distributed import Client, Future

CONNECT_TIMEOUT_S = 10.0
"""How long to wait for an existing scheduler to answer, s."""
DEFAULT_RETRIES = 2
"""Retries of a task after a bug or its worker's death."""


@contextlib.contextmanager
def cluster(scheduler: str | None, workers: int, retries: int = DEFAULT_RETRIES,
            announce: bool = False) -> Iterator[Client]:
    """A client of the scheduler at `scheduler`, or of a new `LocalCluster` of `workers`
    processes (one thread each), closed on exit; with `announce`, the dashboard's address
    (when one is served) is printed on stderr.

    Raises:
        UserError: the scheduler cannot be reached.
    """
    import dask
    from distributed import Client, LocalCluster

    quieten_dask()
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise UserError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there "
                            f"({exc}); start one with `dask scheduler` and its workers with "
                            "`dask worker ADDRESS`, or leave out --scheduler to use this "
                            "machine") from None
        with client:
            _announce(client, announce)
            yield client
        return
    with dask.config.set(local_cluster_config(retries)):
        local = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True)
    with local, Client(local) as client:
        _announce(client, announce)
        yield client


def quieten_dask() -> None:
    """Dask's own records (workers started and stopped) only when micam logs at debug level:
    its "distributed" loggers at WARNING, or at the root logger's level when it is higher."""
    import distributed  # noqa: F401  (sets up its loggers, which the next lines quieten)

    level = logging.getLogger().getEffectiveLevel()
    logging.getLogger("distributed").setLevel(level if level <= logging.DEBUG else
                                              max(level, logging.WARNING))


def local_cluster_config(retries: int) -> dict[str, object]:
    """Dask's configuration for micam's local cluster: `retries` deaths of a task's workers
    allowed, and the nanny's environment for its workers (one-thread BLAS and OpenMP pools)
    without its MALLOC_TRIM_THRESHOLD_, which makes glibc return freed memory at once: a
    calibration allocates and frees large arrays all the time and took 1.7x longer with it
    (0.92 s against 0.55 s, a 3-pose scatter48 session)."""
    import dask

    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ"))
    environ.pop("MALLOC_TRIM_THRESHOLD_", None)
    return {"distributed.scheduler.allowed-failures": retries,
            "distributed.nanny.pre-spawn-environ": environ}


def dashboard(client: Client) -> str | None:
    """The dashboard's address when the scheduler serves one (its plots need bokeh)."""
    services = client.scheduler_info().get("services", {})
    return str(client.dashboard_link) if "dashboard" in services else None


def _announce(client: Client, announce: bool) -> None:
    link = dashboard(client)
    if announce and link:
        print(f"micam: Dask dashboard at {link}", file=sys.stderr)


def submit(client: Client, function: Callable[..., Any], jobs: Sequence[tuple[Any, ...]],
           names: Sequence[str], retries: int = DEFAULT_RETRIES, **keywords: Any
           ) -> list[Future]:
    """One task per job, function(*job, **keywords), retried `retries` times; each task's
    key is its name (shown on the dashboard) made unique to this call."""
    token = uuid.uuid4().hex[:8]
    return client.map(function, *zip(*jobs, strict=True), **keywords, retries=retries,
                      pure=False, key=[f"{name}-{token}" for name in names])


@dataclass(frozen=True)
class _Refused:
    """What a task returns instead of raising the `UserError` of bad input (which no retry
    mends, and which the worker would log as a failed task)."""

    error: UserError


def _call(function: Callable[..., Any], *job: Any) -> Any:
    """function(*job) on a worker, a `UserError` returned as `_Refused`."""
    try:
        return function(*job)
    except UserError as exc:
        return _Refused(exc)


class ClusterMap:
    """function(*job) for every job as tasks on a Dask client's workers, results in the
    jobs' order as they come (a `imaging.parallel.Mapper`). A task refused for
    bad input raises its `UserError` here, at once; one that raised anything else (a bug)
    raises it here after its retries; one whose workers kept dying raises `UserError`."""

    def __init__(self, client: Client, name: str, retries: int = DEFAULT_RETRIES) -> None:
        self.client = client
        self.name = name
        self.retries = retries

    def __call__(self, function: Callable[..., Any], jobs: Sequence[tuple[Any, ...]]
                 ) -> Iterator[Any]:
        from distributed.scheduler import KilledWorker

        if not jobs:
            return
        calls = [(function, *job) for job in _shared(self.client, jobs)]
        futures = submit(self.client, _call, calls,
                         [f"{self.name}-{i}" for i in range(len(jobs))], self.retries)
        try:
            for i, future in enumerate(futures):
                try:
                    result = future.result()
                except KilledWorker:
                    raise UserError(
                        f"{self.name} {i}: the workers running it died, each time (killed, "
                        "or out of memory); the scheduler gave up after "
                        "distributed.scheduler.allowed-failures") from None
                if isinstance(result, _Refused):
                    raise result.error
                yield result
        finally:
            self.client.cancel(futures)


def _shared(client: Client, jobs: Sequence[tuple[Any, ...]]) -> list[tuple[Any, ...]]:
    """The jobs with each argument that all of them share (the same object, e.g. the
    measurements of `cross_validate`'s calibrations) sent to the cluster once
    (`Client.scatter`) and passed as its future, instead of pickled into every task."""
    first = jobs[0]
    if len(jobs) < 2 or any(len(job) != len(first) for job in jobs):
        return list(jobs)
    common = [i for i, value in enumerate(first)
              if not isinstance(value, (type(None), bool, int, float, str, PurePath))
              and all(job[i] is value for job in jobs)]
    if not common:
        return list(jobs)
    sent = dict(zip(common, client.scatter([first[i] for i in common], hash=False),
                    strict=True))
    return [tuple(sent.get(i, value) for i, value in enumerate(job)) for job in jobs]


@contextlib.contextmanager
def cluster_map(name: str, scheduler: str | None, workers: int | None
                ) -> Iterator[ClusterMap | None]:
    """The `ClusterMap` of a study's cells: on the scheduler at `scheduler`, on a local
    cluster of `workers` processes (more than 1), or None (1 or None: run them here, one
    after another), with the command-line checks of the two options.

    Raises:
        UserError: both options given, or the scheduler cannot be reached.
    """
    if scheduler is not None and workers is not None:
        raise UserError("--workers is for a local cluster; an existing cluster (--scheduler) "
                        "has the workers started on it with `dask worker`")
    if scheduler is None and (workers or 1) <= 1:
        yield None
        return
    with cluster(scheduler, workers or 1, announce=True) as client:
        yield ClusterMap(client, name)


def add_cluster_options(parser: argparse.ArgumentParser, tasks: str, shared: str) -> None:
    """A benchmark's --workers and --scheduler (for `cluster_map`): its `tasks` (e.g. "the
    sessions") on a local cluster or an existing scheduler, whose workers must see `shared`
    (e.g. "--keep") at the same path."""
    parser.add_argument("--workers", type=int, default=None,
                        help=f"run {tasks} on a local Dask cluster of N processes "
                             "(default: one after another here)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help=f"run {tasks} on this Dask scheduler (its workers must see "
                             f"{shared})")
