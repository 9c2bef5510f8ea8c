"""How many cores this process may use (for thread and process pools)."""

from __future__ import annotations

import os


def default_workers() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it)."""
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
