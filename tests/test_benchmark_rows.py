"""The benchmarks' tables name what they measure: every row of the realistic lab's error
budget has its magnitude (a camera effect added to the lab without one crashed every cell of
its rows after their sessions were simulated)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_row_of_the_real_lab_budget_has_its_magnitude() -> None:
    bench = _load("bench_real_lab")
    assert set(bench.ROWS) <= set(bench.MAGNITUDES), set(bench.ROWS) - set(bench.MAGNITUDES)


def test_every_mistake_of_the_simulator_is_in_the_mistakes_benchmark() -> None:
    from sim.mistakes import KINDS

    bench = _load("bench_mistakes")
    assert set(bench.EXPECTED) == {kind.name for kind in KINDS}


def test_the_mistakes_benchmark_pairs_each_mistake_with_its_neighbours_or_every_other() -> None:
    bench = _load("bench_mistakes")
    names = ["a", "b", "c", "d"]
    alone = [("a",), ("b",), ("c",), ("d",)]
    assert bench.combinations(names, None) == alone
    assert bench.combinations(names, "next") == alone + [("a", "b"), ("b", "c"), ("c", "d"),
                                                         ("a", "d")]
    assert len(bench.combinations(names, "all")) == 4 + 6
    assert bench.combinations(["a", "b"], "next") == [("a",), ("b",), ("a", "b")]


def test_the_mistakes_benchmark_takes_a_mistake_with_its_arguments() -> None:
    import argparse

    import pytest

    bench = _load("bench_mistakes")
    assert bench._mistake("mjpeg=70") == "mjpeg=70"
    assert bench._kind("mjpeg=70") == "mjpeg"
    with pytest.raises(argparse.ArgumentTypeError, match="unknown mistake 'jpeg'"):
        bench._mistake("jpeg=70")
