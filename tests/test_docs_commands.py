"""Every command the README and docs/*.md give in their shell blocks is one the tree has: each
`micam ...` parses with micam's own parser (every variant of a synopsis, see
tests/doc_commands.py), each benchmark and module exists and takes the options given, each make
target exists; and the cheap, self-contained ones run, in order, in a fresh directory. Every
option the prose names (`micam daemon --make-keys`) exists too. A doc that drifts from the
command line fails here with its file and line."""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib.util
import io
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from micam.cli import EXIT_OK, EXIT_USAGE, build_parser, main
from tests.doc_commands import (REPO, DocCommand, doc_commands, inline_micam_spans,
                                synopsis_variants)

DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
COMMANDS = [c for doc in DOCS for c in doc_commands(doc)]

# other tools' commands the docs give (installing, the system's services, a Dask cluster):
# theirs to keep working, not checked here
OTHER_TOOLS = {"apt-get", "git", "udevadm", "systemctl", "systemd-sysusers", "sudoedit", "pip",
               "dask", ".", "cd"}
PYTHONS = {"python", "python3", ".venv/bin/python"}


def _run_if(*required: str) -> Callable[[list[str]], bool]:
    """Run a variant only when it holds every one of `required` (--dry-run, --emulate)."""
    return lambda words: all(r in words for r in required)


# micam's commands by subcommand: run (when the variant passes the test given) or not, and why.
# A subcommand a doc gives that is in neither fails the test: decide for it here.
RUN: dict[tuple[str, ...], Callable[[list[str]], bool]] = {
    (): _run_if("--version"),
    ("config", "template"): _run_if(),
    # the one written above it (not this machine's /etc/micam/daemon.toml)
    ("config", "check"): lambda words: not Path(words[-1]).is_absolute()
    and Path(words[-1]).exists(),
    ("install", "udev"): _run_if("--dry-run"),
    ("install", "systemd"): _run_if("--dry-run"),
    ("daq", "list"): _run_if("--emulate"),
}
# run on the small simulated session in place of their DIR / SESSION
RUN_ON_A_SESSION = {("inspect",)}
SESSION_PLACEHOLDERS = {"DIR", "SESSION"}
NOT_RUN = {
    ("simulate",): "20-30 poses as written: minutes (parsed only)",
    ("import",): "run as written, in order, by tests/micam/test_docs_import.py",
    ("example", "import"): "run as written, in order, by tests/micam/test_docs_import.py",
    ("calibrate",): "a session calibrated: seconds to minutes (test_docs_import.py runs one)",
    ("batch",): "many sessions, a Dask cluster: minutes",
    ("study",): "simulations and calibrations on a cluster: minutes",
    ("image",): "needs a calibrated session",
    ("evaluate-imaging",): "a 30-pose session, cross-validated: minutes",
    ("daq", "selftest"): "scans every (emulated) board: 2 s; tests/acquisition/test_cli_daq.py",
    ("daq", "probe"): "probes every (emulated) board: 1 s; tests/daq/test_usb_probe.py",
    ("daq", "trace", "show"): "needs a USB capture (FILE)",
    ("daq", "trace", "diff"): "needs two USB captures",
    ("daemon",): "runs until stopped, on the hardware (or its configuration)",
    ("worker",): "runs until stopped, beside a running daemon",
    ("web",): "runs until stopped, beside a running daemon",
    ("session", "start"): "needs a running daemon",
    ("session", "status"): "needs a running daemon",
    ("session", "pause"): "needs a running daemon",
    ("session", "resume"): "needs a running daemon",
    ("session", "stop"): "needs a running daemon",
    ("session", "abort"): "needs a running daemon",
    ("capture",): "needs a running daemon",
    ("watch",): "needs a running daemon; runs until stopped",
    ("sessions",): "needs a running daemon",
    ("live", "start"): "needs a running daemon",
    ("live", "stop"): "needs a running daemon",
    ("live", "video"): "needs a running daemon in live mode (or its recording)",
    ("live", "record"): "needs a running daemon in live mode",
}


@functools.cache
def _script_options(script: Path) -> frozenset[str]:
    """The options `script --help` lists: its own and any it takes from a shared helper
    (micam.cluster.add_cluster_options), which its source alone would not show."""
    shown = subprocess.run([sys.executable, str(script), "--help"], cwd=REPO, text=True,
                           capture_output=True, timeout=120, check=True).stdout
    return frozenset(re.findall(r"--[\w-]+", shown))


@functools.cache
def _parser() -> argparse.ArgumentParser:
    """micam's parser, built once: parsing leaves it as it was."""
    return build_parser()


def _subcommand(parser: argparse.ArgumentParser, words: list[str]) -> tuple[str, ...]:
    """The (nested) subcommand `words` (micam's arguments) names: ("daq", "trace", "show")."""
    path: list[str] = []
    for word in words:
        choices = next((a.choices for a in parser._actions  # argparse has no public walk
                        if isinstance(a, argparse._SubParsersAction)), None)
        if choices is None or word.startswith("-"):
            break
        if word not in choices:
            break
        path.append(word)
        parser = choices[word]
    return tuple(path)


def _command_parser(words: list[str]) -> tuple[argparse.ArgumentParser, tuple[str, ...]]:
    """The parser of the (nested) subcommand `words` names, and its path."""
    parser, path = _parser(), _subcommand(_parser(), words)
    for name in path:
        parser = next(a.choices for a in parser._actions
                      if isinstance(a, argparse._SubParsersAction))[name]
    return parser, path


def _parse_error(words: list[str], elided: bool) -> str | None:
    """argparse's complaint about `micam words`, or None; an elided synopsis (`...`) may leave
    required arguments out."""
    stderr = io.StringIO()
    try:
        with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
            _parser().parse_args(words)
    except SystemExit as exit:
        message = stderr.getvalue().strip().splitlines()[-1:] or [""]
        if exit.code != 0 and not (elided and "arguments are required" in message[0]):
            return message[0]
    return None


def _abbreviated(words: list[str]) -> list[str]:
    """The options of `micam words` not written out (argparse takes `--camera-f` for
    `--camera-fps` until another option begins so)."""
    parser, _ = _command_parser(words)
    return [w.split("=")[0] for w in words if w.startswith("--")
            and w.split("=")[0] not in parser._option_string_actions]


def _micam_commands() -> list[DocCommand]:
    return [c for c in COMMANDS if c.program == "micam"]


def test_the_docs_give_commands() -> None:
    """The reader finds them: a broken fence or a renamed block would check nothing."""
    by_doc = {c.doc for c in _micam_commands()}
    assert {"README.md", "docs/import.md", "docs/live.md", "docs/batch.md"} <= by_doc, by_doc
    assert len(_micam_commands()) > 50


@pytest.mark.parametrize("command", _micam_commands(), ids=lambda c: c.where)
def test_every_micam_command_of_the_docs_parses(command: DocCommand) -> None:
    elided = "..." in command.words
    for variant in synopsis_variants(command.words[1:]):
        error = _parse_error(variant, elided)
        assert error is None, f"{command.where}: micam {' '.join(variant)}: {error}"
        abbreviated = _abbreviated(variant)
        assert not abbreviated, f"{command.where}: write out {abbreviated} (argparse guesses)"
        path = _subcommand(_parser(), variant)
        assert path in RUN or path in RUN_ON_A_SESSION or path in NOT_RUN, \
            f"{command.where}: micam {' '.join(path)}: add it to RUN, RUN_ON_A_SESSION or NOT_RUN"


def test_a_removed_option_fails_the_check() -> None:
    """The check can fail: an option micam does not have is named, with the doc's line."""
    assert "--no-such" in (_parse_error(["simulate", "--out", "s", "--no-such"], False) or "")
    assert _parse_error(["session", "begin"], False)
    assert _abbreviated(["live", "start", "--camera-f", "10"]) == ["--camera-f"]
    assert synopsis_variants(("calibrate", "DIR", "[--method", "micam|paper]")) == [
        ["calibrate", "DIR", "--method", "micam"], ["calibrate", "DIR", "--method", "paper"],
        ["calibrate", "DIR"]]


@pytest.mark.parametrize("doc", DOCS, ids=lambda d: str(d.relative_to(REPO)))
def test_every_micam_option_the_prose_names_exists(doc: Path) -> None:
    """`micam daemon --make-keys` in a sentence: the subcommand has that option (the value, often
    left out in prose, is not checked)."""
    unknown = []
    for line, words in inline_micam_spans(doc):
        parser, path = _command_parser(words)
        if words and not words[0].startswith("-") and not path:
            unknown.append(f"{doc.name}:{line}: micam {words[0]}")
        options = [re.sub(r"[=\]),.;:].*$", "", w.lstrip("[(")) for w in words]
        unknown += [f"{doc.name}:{line}: micam {' '.join(path)} {o}" for o in options
                    if o.startswith("--") and o not in parser._option_string_actions]
    assert not unknown, unknown


@pytest.mark.parametrize("command", [c for c in COMMANDS if c.program != "micam"],
                         ids=lambda c: c.where)
def test_every_other_command_of_the_docs_exists(command: DocCommand) -> None:
    program, args = Path(command.program).name or command.program, list(command.words[1:])
    if command.program in PYTHONS or program in PYTHONS:
        if args[0] == "-m":
            assert importlib.util.find_spec(args[1]), f"{command.where}: no module {args[1]}"
            return
        script = REPO / args[0]
        assert script.is_file(), f"{command.where}: no {args[0]}"
        missing = [a for a in args[1:] if a.startswith("--") and a not in _script_options(script)]
        assert not missing, f"{command.where}: {args[0]} has no {missing}"
    elif program == "make":
        targets = re.findall(r"^([\w-]+):", (REPO / "Makefile").read_text(), flags=re.M)
        assert set(args) <= set(targets), f"{command.where}: make has no {args}"
    else:
        assert program in OTHER_TOOLS, f"{command.where}: {program}: not micam's; name it in" \
            " OTHER_TOOLS or check it here"


@pytest.mark.parametrize("doc", [d for d in DOCS if any(
    c.doc == str(d.relative_to(REPO)) and c.program == "micam" for c in COMMANDS)],
                         ids=lambda d: str(d.relative_to(REPO)))
def test_the_cheap_commands_run_as_written(doc: Path, tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """In order, in a fresh directory per section (the boards' and a sound card's are two
    labs): a configuration written is the one checked next. The docs check a template before
    the edit they ask for only to show the check's refusal of its CHANGE-ME."""
    parser = _parser()
    for command in (c for c in COMMANDS if c.doc == str(doc.relative_to(REPO))
                    and c.program == "micam"):
        world = tmp_path / (re.sub(r"\W+", "-", command.section) or "top")
        world.mkdir(exist_ok=True)
        for k, variant in enumerate(synopsis_variants(command.words[1:])):
            monkeypatch.chdir(world)
            path = _subcommand(parser, variant)
            if path not in RUN or not RUN[path](variant):
                continue
            if k > 0:  # an alternative (`paper|generic --out daemon.toml`) in a directory of
                # its own: the commands that follow see the first
                (world / f"{command.line}-{k}").mkdir()
                monkeypatch.chdir(world / f"{command.line}-{k}")
            try:
                status = main(variant)
            except SystemExit as exit:  # --version
                status = int(exit.code or 0)
            out, err = capsys.readouterr()
            refused_template = path == ("config", "check") and "CHANGE-ME" in err
            assert status == EXIT_OK or status == EXIT_USAGE and refused_template, \
                f"{command.where}: micam {' '.join(variant)} -> {status}:\n{out}\n{err}"
            assert out or err, f"{command.where}: micam {' '.join(variant)} said nothing"


@pytest.mark.slow  # the small simulated session (shared, once per run): 4 s alone
def test_the_session_commands_run_as_written_on_a_session(small_session: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    ran = 0
    for command in _micam_commands():
        for variant in synopsis_variants(command.words[1:]):
            if _subcommand(_parser(), variant) not in RUN_ON_A_SESSION:
                continue
            words = [str(small_session) if w in SESSION_PLACEHOLDERS else w for w in variant]
            status = main(words)
            out, err = capsys.readouterr()
            assert status == EXIT_OK and str(small_session) in out, \
                f"{command.where}: micam {' '.join(words)} -> {status}:\n{out}\n{err}"
            ran += 1
    assert ran, "no doc gives these commands: drop RUN_ON_A_SESSION"
