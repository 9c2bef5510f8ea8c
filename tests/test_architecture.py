"""The shape of the code: the import-linter layer contracts, no import cycle, mypy clean.

CI runs exactly the test command of README.md, so these checks live in the test suite:
`lint-imports` with the contracts of pyproject.toml, a cycle search over the graph of the
top-level packages (import-linter's own `acyclic_siblings` covers the siblings inside each
package), and mypy over every package and the tests (its cache in .venv, so a second run takes
seconds).
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path

import grimp
import pytest

REPO = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
PACKAGES = PYPROJECT["tool"]["importlinter"]["root_packages"]


def _tool(name: str) -> str:
    """A console script installed beside this interpreter (the virtual environment's)."""
    path = Path(sys.executable).parent / name
    if not path.exists():
        pytest.fail(f"{name} is not installed in {path.parent}: pip install -e '.[test]'")
    return str(path)


def find_cycle(edges: Mapping[str, Iterable[str]]) -> list[str] | None:
    """One cycle of the directed graph `edges` (node -> the nodes it imports), as the list of
    its nodes with the first repeated at the end, or None when the graph has none."""
    state: dict[str, int] = {}  # 1: on the current path, 2: finished
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(edges.get(node, ())):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt):], nxt]
            if nxt not in state and (cycle := visit(nxt)) is not None:
                return cycle
        path.pop()
        state[node] = 2
        return None

    for start in sorted(edges):
        if start not in state and (cycle := visit(start)) is not None:
            return cycle
    return None


def test_find_cycle_finds_one_and_only_one() -> None:
    assert find_cycle({"a": ["b"], "b": ["c"], "c": []}) is None
    assert find_cycle({"a": ["b"], "b": ["c"], "c": ["a"]}) == ["a", "b", "c", "a"]


def test_no_import_cycle_between_the_top_level_packages() -> None:
    graph = grimp.build_graph(*PACKAGES, exclude_type_checking_imports=True, cache_dir=None)
    edges: dict[str, set[str]] = {p: set() for p in PACKAGES}
    for module in graph.modules:
        for imported in graph.find_modules_directly_imported_by(module):
            a, b = module.split(".")[0], imported.split(".")[0]
            if a != b:
                edges[a].add(b)
    assert find_cycle(edges) is None, f"import cycle between packages: {find_cycle(edges)}"


def test_the_forbidden_list_names_every_service_module_of_acquisition() -> None:
    """calibration and sim may import acquisition.contracts only: the contract lists every
    other child of acquisition, so a new module there is covered the day it is added."""
    [contract] = [c for c in PYPROJECT["tool"]["importlinter"]["contracts"]
                  if c["id"] == "contracts-only"]
    children = {p.stem for p in (REPO / "acquisition").iterdir()
                if (p.suffix == ".py" and p.stem != "__init__") or (p / "__init__.py").exists()}
    listed = {m.removeprefix("acquisition.") for m in contract["forbidden_modules"]}
    assert children - {"contracts"} == listed


def test_import_contracts_hold() -> None:
    run = subprocess.run([_tool("lint-imports"), "--no-cache"], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-2000:]
    assert "0 broken" in run.stdout


@pytest.mark.slow
def test_mypy_is_clean() -> None:
    run = subprocess.run([sys.executable, "-m", "mypy"], cwd=REPO, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]


def test_every_test_has_a_timeout(pytestconfig: pytest.Config) -> None:
    """pytest-timeout ends a hung test with the stacks of its threads instead of hanging CI."""
    assert pytestconfig.pluginmanager.hasplugin("timeout")
    assert float(pytestconfig.getini("timeout")) > 0


def test_no_module_is_named_like_a_standard_library_module() -> None:
    """A module named `operator.py` or `inspect.py` reads as the standard library's in a
    traceback and in a reader's head (issue 18 renamed the last ones)."""
    shadowing = sorted(
        str(path.relative_to(REPO)) for package in PACKAGES
        for path in (REPO / package).rglob("*.py")
        if path.stem in sys.stdlib_module_names and path.stem != "__init__")
    assert not shadowing, f"rename these modules: {shadowing}"
