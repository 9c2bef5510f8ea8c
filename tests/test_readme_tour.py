"""README's newcomer's tour matches the tree: every path it names exists, and it names every
package and subpackage there is (a move or a new package that forgets the tour fails here)."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ROOTS = ("micam/", "imaging/", "acquisition/", "calibration/", "sim/", "daq/", "kernel/",
         "tests/", "benchmarks/", "docs/", "udev/", "pyproject.toml")


def _tour() -> str:
    text = (REPO / "README.md").read_text()
    start = text.index("## A newcomer's tour")
    end = text.index("\n## ", start + 1)
    return text[start:end]


def _rows() -> dict[str, str]:
    """The tour's table rows by their package path (`acquisition/contracts/`, ...)."""
    rows = {}
    for line in _tour().splitlines():
        if m := re.match(r"\| `([\w/]+/)` \|", line):
            rows[m.group(1)] = line
    return rows


def _named(text: str) -> set[str]:
    return {t for t in re.findall(r"`([^`\s]+)`", text) if t.endswith(("/", ".py", ".toml"))}


def test_every_path_the_tour_names_exists() -> None:
    missing = [t for t in _named(_tour()) if t.startswith(ROOTS) and not (REPO / t).exists()]
    for package, row in _rows().items():
        missing += [f"{package}{t}" for t in _named(row)
                    if not t.startswith(ROOTS) and not (REPO / package / t).exists()]
    assert not missing, f"the tour names paths that do not exist: {missing}"


def test_the_tour_names_every_package_and_subpackage() -> None:
    rows = _rows()
    packages = sorted(p.parent.name + "/" for p in REPO.glob("*/__init__.py")
                      if p.parent.name != "tests")
    assert [p for p in packages if p not in rows] == []
    unnamed = []
    for package in packages:
        for sub in sorted((REPO / package).glob("*/__init__.py")):
            rel = f"{package}{sub.parent.name}/"
            row = rows.get(rel) or rows[package]
            if rel not in rows and f"`{sub.parent.name}/`" not in row and f"`{rel}`" not in row:
                unnamed.append(rel)
    assert not unnamed, f"subpackages the tour does not name: {unnamed}"
