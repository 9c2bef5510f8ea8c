"""What keeps a command from writing where it was told to, found before any work is done.

A session import or a simulation takes minutes; an output directory that cannot be one (a
dangling symbolic link, a file, a directory that is not empty, a parent that is a file) must
be refused at once, in words, not end in a traceback after the work. The command line
(`micam.outputs`) and the importer's own API ask the same question here.
"""

from __future__ import annotations

import os
from pathlib import Path


def dangling_link_problem(path: Path) -> str | None:
    """What is wrong with `path` if it is a symbolic link to nothing, else None."""
    if path.is_symlink() and not path.exists():
        return (f"is a symbolic link to {os.readlink(path)}, which does not exist; remove the "
                "link or name another path")
    return None


def new_directory_problem(path: Path, reuse: bool = False) -> str | None:
    """Why no new directory can be made at `path` (a phrase to follow the path), or None.

    Refused: a dangling symbolic link, a file, a directory that is not empty (accepted with
    `reuse`: a directory whose files the caller replaces), a missing path whose nearest
    existing ancestor is a file or not writable (missing parents are made by the caller).
    """
    dangling = dangling_link_problem(path)
    if dangling:
        return dangling
    if path.exists():
        if not path.is_dir():
            return "is a file, not a directory; name a new directory"
        if not reuse and any(path.iterdir()):
            return ("is not empty; name a new or empty directory (nothing in an existing one "
                    "is overwritten)")
        return None
    ancestor = next(p for p in path.absolute().parents if p.exists() or p.is_symlink())
    if dangling_link_problem(ancestor) or not ancestor.is_dir():
        return f"lies under {ancestor}, which is not a directory; name a path under a directory"
    if not os.access(ancestor, os.W_OK | os.X_OK):
        return (f"cannot be created in {ancestor}: it is not writable (a read-only disk, or no "
                "permission); name a path on a writable disk")
    return None
