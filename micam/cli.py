"""`micam`: the one command-line entry point, with a subcommand per job.

Each subcommand lives in its own module (`micam/commands/…`) and registers itself here;
heavy imports happen only when a subcommand runs, so `micam --help` is instant.

Every failure ends in one line on stderr, `micam: error: ...`, and one of the exit statuses
below (README, "Exit status"); `--debug` shows the traceback instead. Bad input is an
`acquisition.contracts.errors.UserError` (exit 2); anything else is a bug (exit 70), whose
traceback goes to a file in the bug log directory that the line names.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
import traceback
from collections.abc import Sequence
from pathlib import Path

from .commands import (
    calibrate,
    capture,
    config,
    daemon,
    daq,
    evaluate_imaging,
    example,
    image,
    import_session,
    inspect_session,
    install,
    live,
    session,
    sessions,
    simulate,
    study,
    watch,
    web,
    worker,
)
from .batch import command as batch
from acquisition.contracts.errors import UserError
from acquisition.daemon.systemd import StderrHandler

SUBCOMMANDS = (
    simulate, example, import_session, inspect_session, calibrate, batch, study, image,
    evaluate_imaging, daq,
    daemon, config, session,
    capture, watch, sessions, web, live,
    worker, install,
)

EXIT_OK = 0
EXIT_FAILED = 1
"""The command ran and found a problem (a check failed, a board failed its self-test)."""
EXIT_USAGE = 2
"""Bad options or input: a missing file, an invalid configuration, a daemon that refused."""
EXIT_INCOMPLETE = 3
"""A capture did not complete (abandoned, or interrupted: resume it)."""
EXIT_INTERNAL = 70
"""A bug in micam (sysexits' EX_SOFTWARE): the one-line error says what; `--debug` shows where."""
EXIT_INTERRUPTED = 130
"""Ctrl-C (128 + SIGINT)."""
EXIT_PIPE_CLOSED = 141
"""The reader of the output went away (`micam sessions | head`), as a shell reports SIGPIPE."""

LOG_LEVELS = ("debug", "info", "warning", "error")
BUG_DIR_ENV = "MICAM_BUG_DIR"
"""Where a bug's traceback is written (default: $XDG_STATE_HOME/micam/bugs)."""

log = logging.getLogger("micam")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("micam")
    except PackageNotFoundError:  # run from a checkout that was never installed
        return "unknown (not installed)"


def _common_options(parser: argparse.ArgumentParser, default: object) -> None:
    """--debug and --log-level, accepted before or after the subcommand's name."""
    parser.add_argument("--debug", action="store_true", default=default,
                        help="on an error, show its traceback instead of the one-line message")
    parser.add_argument("--log-level", choices=LOG_LEVELS, default=default,
                        help="the lowest level of log messages shown on stderr "
                             "(default: $MICAM_LOG_LEVEL or info)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="micam",
        description="Calibrate acoustic cameras and run their capture hardware.",
        epilog="Exit status: 0 done, 1 a check failed, 2 bad options or input, 3 a capture "
               "did not complete, 70 a bug in micam, 130 interrupted, 141 output pipe closed.",
    )
    _common_options(parser, None)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in SUBCOMMANDS:
        module.register(sub)
    for command in {id(p): p for p in sub.choices.values()}.values():
        _common_options(command, argparse.SUPPRESS)
    version = f"micam {_version()}"
    for command in _every_parser(parser):  # `micam session start --version` too
        command.add_argument("--version", action="version", version=version,
                             help="print micam's version and exit")
    return parser


def _every_parser(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    """`parser` and every (sub)command's parser under it, each once (aliases share one)."""
    found = {id(parser): parser}
    for action in parser._actions:  # argparse has no public walk of its subcommands
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                for p in _every_parser(child):
                    found.setdefault(id(p), p)
    return list(found.values())


def _log_level(args: argparse.Namespace) -> int:
    name = args.log_level or os.environ.get("MICAM_LOG_LEVEL", "info").lower()
    if name not in LOG_LEVELS:
        raise UserError(f"MICAM_LOG_LEVEL={name!r} is not one of {', '.join(LOG_LEVELS)}")
    return int(getattr(logging, name.upper()))


def _log_to_stderr(level: int) -> None:
    """The commands' log messages on stderr from `level` up (the daemon and the worker set
    up their own, journald-aware logging)."""
    root = logging.getLogger()
    if not any(isinstance(h, StderrHandler) for h in root.handlers):
        handler = StderrHandler()
        handler.setFormatter(logging.Formatter("micam: %(levelname)s %(name)s: %(message)s"))
        root.addHandler(handler)
    root.setLevel(level)


def _pipe_closed() -> int:
    """The reader of stdout went away: drop what is left unwritten and end quietly."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout is not a file descriptor (tests)
        pass
    return EXIT_PIPE_CLOSED


def main(argv: Sequence[str] | None = None) -> int:
    """Run the `micam` command line; returns the process exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    debug = bool(args.debug)
    try:
        args.log_level = _log_level(args)
        _log_to_stderr(args.log_level)
        status = int(args.run(args) or 0)
        sys.stdout.flush()
        return status
    except KeyboardInterrupt:
        print("micam: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return _pipe_closed()
    except UserError as exc:
        if debug:
            raise
        print(f"micam: error: {exc}", file=sys.stderr)  # a configuration's: a line per problem
        return EXIT_USAGE
    except Exception as exc:
        if debug:
            raise
        where = _write_bug_log(exc, argv)
        log.debug("a bug in micam", exc_info=exc)
        print(f"micam: error: {_one_line(exc)} ({type(exc).__name__}; this is a bug in micam "
              f"{_version()}: {where}, and report it)", file=sys.stderr)
        return EXIT_INTERNAL


def _write_bug_log(exc: BaseException, argv: Sequence[str] | None) -> str:
    """Write `exc`'s traceback (with the command line and micam's version) to a new file in
    the bug log directory, `$MICAM_BUG_DIR`, else `$XDG_STATE_HOME/micam/bugs`, else
    `~/.local/state/micam/bugs`; say where it is (or, if nothing can be written there, that
    --debug shows it)."""
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    directory = Path(os.environ.get(BUG_DIR_ENV) or Path(state) / "micam" / "bugs")
    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
    command = " ".join(sys.argv[:1] + list(sys.argv[1:] if argv is None else argv))
    text = (f"micam {_version()}, Python {sys.version.split()[0]}, {stamp}Z\n$ {command}\n\n"
            + "".join(traceback.format_exception(exc)))
    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f"bug-{stamp}-", suffix=".txt", dir=directory)
        with os.fdopen(fd, "w", encoding="utf-8", errors="backslashreplace") as fh:
            fh.write(text)
    except OSError:
        return "run again with --debug for the traceback"
    return f"the traceback is in {name}"


def _one_line(exc: BaseException) -> str:
    """The message of an error on one line (a multi-line one joined with "; ")."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return "; ".join(lines) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
