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
