"""The burst is one concept (acquisition/contracts/burst.py): the capture's burst, the
description's layout, the simulation's options, the command line's options and the sequence
generator take one set of bounds, and the description's layout is derived from the capture's.

A second set of bounds anywhere (a model's own `ge=`/`le=`, an option's own `integer(6, 18)`)
makes one of these entry points accept or refuse a value the burst does not, and fails here.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import pytest
from pydantic import ValidationError

from acquisition.contracts.burst import MAX_PERIODS, BurstConfig, BurstLayout
from kernel.stimulus import MAX_MLS_ORDER, MIN_MLS_ORDER, mls_burst, mls_length
from micam.cli import build_parser
from sim.capture import SimulationOptions

BOUNDS = {"mls_order": (MIN_MLS_ORDER, MAX_MLS_ORDER), "periods": (1, MAX_PERIODS)}


def _option(command: str, flag: str) -> Callable[[str], object]:
    """The argparse type of `micam COMMAND FLAG`."""
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    action = next(a for a in commands.choices[command]._actions if flag in a.option_strings)
    assert action.type is not None
    return action.type


ENTRY_POINTS: dict[str, tuple[str, Callable[[int], object]]] = {
    "BurstConfig.mls_order": ("mls_order", lambda v: BurstConfig(mls_order=v)),
    "BurstLayout.mls_order": ("mls_order", lambda v: BurstLayout(mls_order=v)),
    "SimulationOptions.mls_order": ("mls_order",
                                    lambda v: SimulationOptions(mls_order=v, mls_periods=1)),
    "micam simulate --mls-order": ("mls_order", lambda v: _option("simulate", "--mls-order")(
        str(v))),
    "micam study --mls-order": ("mls_order", lambda v: _option("study", "--mls-order")(str(v))),
    "kernel.stimulus.mls_burst": ("mls_order", mls_burst),
    "BurstConfig.periods": ("periods", lambda v: BurstConfig(periods=v)),
    "BurstLayout.periods": ("periods", lambda v: BurstLayout(mls_order=14, periods=v)),
    "SimulationOptions.mls_periods": ("periods",
                                      lambda v: SimulationOptions(mls_order=14, mls_periods=v)),
    "micam simulate --mls-periods": ("periods", lambda v: _option("simulate", "--mls-periods")(
        str(v))),
}


def _accepts(make: Callable[[int], object], value: int) -> bool:
    try:
        make(value)
    except (ValidationError, ValueError, argparse.ArgumentTypeError):
        return False
    return True


@pytest.mark.parametrize("name", sorted(ENTRY_POINTS))
def test_every_entry_point_of_a_burst_takes_the_bursts_bounds(name: str) -> None:
    field, make = ENTRY_POINTS[name]
    lo, hi = BOUNDS[field]
    verdicts = {v: _accepts(make, v) for v in (lo - 1, lo, hi, hi + 1)}
    assert verdicts == {lo - 1: False, lo: True, hi: True, hi + 1: False}, name


def test_the_descriptions_layout_is_the_captures_burst() -> None:
    burst = BurstConfig(mls_order=12, periods=3, pre_samples=100, post_samples=200)
    layout = burst.as_recorded()
    assert layout == BurstLayout(silence_before_samples=100, mls_order=12, periods=3,
                                 silence_after_samples=200)
    assert burst.n_samples == layout.n_samples == 100 + 3 * mls_length(12) + 200
    assert layout.steady_window == (100 + 2 * mls_length(12), 100 + 3 * mls_length(12))

