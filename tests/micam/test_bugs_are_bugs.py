"""A bug is reported as a bug, bad input as bad input (issue #26, finding 9).

Input errors derive from one root, `acquisition.contracts.errors.UserError` (each layer has its
own type below it); the command line and the worker catch only those. Anything else, a
`ValueError` from a broadcasting mistake in the solver say, is a bug: the command line exits 70
and writes the traceback to its bug log; the worker logs the traceback and marks the job
retryable (another worker, or a fixed version, may succeed): that test is in
tests/calibration/worker/test_bad_input.py.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import micam.cli as cli
from micam.cli import main

REPO = Path(__file__).resolve().parents[2]
BROADCAST_BUG = "operands could not be broadcast together with shapes (3,) (4,)"


def inject_solver_bug(monkeypatch: pytest.MonkeyPatch) -> None:
    """The microphone solver fails as a programming error would."""
    import calibration.pipeline

    def broken_solve(*_args: object, **_kwargs: object) -> None:
        raise ValueError(BROADCAST_BUG)

    monkeypatch.setattr(calibration.pipeline, "solve", broken_solve)


def test_a_bug_in_the_solver_exits_70_with_its_traceback_in_the_bug_log(
        small_session: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv(cli.BUG_DIR_ENV, str(tmp_path / "bugs"))
    inject_solver_bug(monkeypatch)
    status = main(["calibrate", str(small_session), "--out", str(tmp_path / "r.json"),
                   "--no-joint"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert status == cli.EXIT_INTERNAL, err
    assert BROADCAST_BUG in err and "this is a bug in micam" in err
    [log] = (tmp_path / "bugs").iterdir()
    text = log.read_text()
    assert "Traceback (most recent call last)" in text and "broken_solve" in text
    assert f"ValueError: {BROADCAST_BUG}" in text
    assert not (tmp_path / "r.json").exists()


def test_bad_input_to_the_same_command_is_still_status_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "empty").mkdir()
    assert main(["calibrate", str(tmp_path / "empty"), "--out",
                 str(tmp_path / "r.json")]) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert err.startswith("micam: error: ") and "bug" not in err


# -- the class stays closed -----------------------------------------------------------------

CATCHERS = [(path, None) for path in sorted((REPO / "micam" / "commands").glob("*.py"))] + [
    (REPO / "calibration" / "worker" / "worker.py", "_work"),
    (REPO / "micam" / "batch" / "cells.py", "run_cell")]
"""The code that turns errors into exit statuses or job outcomes: every command, the
worker's job thread (its message parsing may catch ValueError: that is reading input), and
a batch's cell (its errors become the failed rows of the batch's table)."""
LIBRARIES = ("acquisition", "calibration", "imaging", "sim", "daq", "kernel", "micam")


def _library_names(tree: ast.Module) -> set[str]:
    """Names the module binds by importing from micam's own packages (anywhere in it)."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (
                node.level > 0 or (node.module or "").split(".")[0] in LIBRARIES):
            names.update(alias.asname or alias.name for alias in node.names)
    return names


def _catches_value_error(handler: ast.ExceptHandler) -> bool:
    types = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
    return any(isinstance(t, ast.Name) and t.id == "ValueError" for t in types)


def _calls_into(body: list[ast.stmt], names: set[str]) -> list[str]:
    """The names of `names` that `body` calls (directly or as `name.attribute(...)`)."""
    called = []
    for node in ast.walk(ast.Module(body=body, type_ignores=[])):
        if isinstance(node, ast.Call):
            func = node.func
            while isinstance(func, ast.Attribute):
                func = func.value
            if isinstance(func, ast.Name) and func.id in names:
                called.append(func.id)
    return called


@pytest.mark.parametrize(("path", "function"), CATCHERS,
                         ids=[str(p.relative_to(REPO)) for p, _ in CATCHERS])
def test_no_command_turns_a_library_value_error_into_bad_input(path: Path,
                                                               function: str | None) -> None:
    """Catching ValueError around micam's own code would report its bugs as bad input: only
    the parsing of an option's text (float(), int(), ...) may be wrapped so."""
    tree = ast.parse(path.read_text())
    names = _library_names(tree)
    scope: ast.AST = tree if function is None else next(
        n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and n.name == function)
    wrong = [f"line {node.lineno}: {', '.join(sorted(set(calls)))}"
             for node in ast.walk(scope) if isinstance(node, ast.Try)
             if any(_catches_value_error(h) for h in node.handlers)
             if (calls := _calls_into(node.body, names))]
    assert not wrong, (f"{path.relative_to(REPO)} catches ValueError around micam's own "
                       f"calls (raise the layer's input error there instead): {wrong}")
