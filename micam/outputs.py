"""Checks of the files and directories a command will write, made before the work starts.

A calibration, an import or an imaging run takes minutes; an output that cannot be written
must fail at once with a one-line error naming the option, not after the work with a
traceback (and half of its outputs written). Every `--out`-like option goes through one of
the two checks here: `check_outputs` for files, `check_output_dirs` for new directories.
Missing parent directories are made, as `mkdir -p` would (`--out lab/import.toml` with no
`lab/` yet): only where they can be, under a writable directory.
"""

from __future__ import annotations

import os
from pathlib import Path

from acquisition.contracts.errors import UserError
from acquisition.contracts.output_paths import dangling_link_problem, new_directory_problem


def check_outputs(*outputs: tuple[str, Path | None]) -> None:
    """UserError naming the option when an output file (`(flag, path)`, None: not asked for)
    cannot be written: a dangling symbolic link, a directory, or a directory that is
    read-only or cannot be made; missing parent directories are made (once every output is
    known to be writable)."""
    missing = []
    for flag, path in outputs:
        if path is None:
            continue
        dangling = dangling_link_problem(path)
        if dangling:
            raise UserError(f"{flag} {path} {dangling}")
        parent = path.absolute().parent
        if not parent.is_dir():
            problem = new_directory_problem(parent, reuse=True)
            if problem:
                raise UserError(f"the directory of {flag} ({parent}) {problem}")
            missing.append(parent)
            continue
        if path.is_dir():
            raise UserError(f"{flag} {path} is a directory; name a file")
        if not os.access(parent, os.W_OK):
            raise UserError(f"{flag}: cannot write in {parent} (no permission)")
    for parent in missing:
        parent.mkdir(parents=True, exist_ok=True)


def check_output_dirs(*outputs: tuple[str, Path | None], session_hint: str = "",
                      reuse: bool = False) -> None:
    """UserError naming the option when a new directory (`(flag, path)`, None: not asked for)
    cannot be made at `path` (`new_directory_problem`; with `reuse` an existing directory is
    accepted, its files replaced). A directory that holds a session is named as such, with
    `session_hint` saying what to do instead."""
    from acquisition.contracts.session import JOURNAL_NAME  # here: `micam --help` stays light

    for flag, path in outputs:
        if path is None:
            continue
        if not reuse and (path / JOURNAL_NAME).exists():
            raise UserError(f"{path} already holds a session, which is never overwritten: "
                            f"{session_hint}choose a new {flag}")
        problem = new_directory_problem(path, reuse)
        if problem:
            raise UserError(f"{flag} {path} {problem}")
