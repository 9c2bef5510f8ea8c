"""Checks of the files and directories a command will write, made before the work starts.

A calibration, an import or an imaging run takes minutes; an output that cannot be written
must fail at once with a one-line error naming the option, not after the work with a
traceback (and half of its outputs written). Every `--out`-like option goes through one of
the two checks here: `check_outputs` for files, `check_output_dirs` for new directories.
"""

from __future__ import annotations

import os
from pathlib import Path

from acquisition.contracts.errors import UserError


def check_outputs(*outputs: tuple[str, Path | None]) -> None:
    """UserError naming the option when an output file (`(flag, path)`, None: not asked for)
    cannot be written: a dangling symbolic link, a directory, or a directory that is missing
    or read-only."""
    for flag, path in outputs:
        if path is None:
            continue
        _refuse_dangling_link(flag, path)
        parent = path.absolute().parent
        if not parent.is_dir():
            raise UserError(f"the directory of {flag} ({parent}) does not exist; create it "
                            "first")
        if path.is_dir():
            raise UserError(f"{flag} {path} is a directory; name a file")
        if not os.access(parent, os.W_OK):
            raise UserError(f"{flag}: cannot write in {parent} (no permission)")


def check_output_dirs(*outputs: tuple[str, Path | None], session_hint: str = "") -> None:
    """UserError naming the option when a new directory (`(flag, path)`, None: not asked for)
    cannot be made at `path`: a dangling symbolic link, a file, a directory that is not
    empty (one that holds a session: `session_hint` says what to do instead), or a missing
    path whose nearest existing ancestor is a file or read-only (missing parents are made)."""
    from acquisition.contracts.session import JOURNAL_NAME

    for flag, path in outputs:
        if path is None:
            continue
        _refuse_dangling_link(flag, path)
        if path.exists():
            if not path.is_dir():
                raise UserError(f"{flag} {path} is a file, not a directory; name a new "
                                "directory")
            if (path / JOURNAL_NAME).exists():
                raise UserError(f"{path} already holds a session, which is never "
                                f"overwritten: {session_hint or ''}choose a new {flag}")
            if any(path.iterdir()):
                raise UserError(f"{flag} {path} is not empty; name a new or empty directory "
                                "(nothing in an existing one is overwritten)")
            continue
        ancestor = next(p for p in path.absolute().parents if p.exists() or p.is_symlink())
        _refuse_dangling_link(flag, ancestor)
        if not ancestor.is_dir():
            raise UserError(f"{flag} {path}: {ancestor} is a file, not a directory; name a "
                            "path under a directory")
        if not os.access(ancestor, os.W_OK | os.X_OK):
            raise UserError(f"{flag} {path}: cannot create it in {ancestor} (no permission)")


def _refuse_dangling_link(flag: str, path: Path) -> None:
    if path.is_symlink() and not path.exists():
        raise UserError(f"{flag} {path} is a symbolic link to {os.readlink(path)}, which does "
                        "not exist; remove the link or name another path")
