"""Crash-safe file primitives: durable directories and write-to-partial-then-rename.

A rename is atomic but only durable once the parent directory is fsync'd, so every function here
ends with that fsync. A file therefore exists under its final name either complete or not at all;
after a crash only `*.partial` files can be incomplete, and `remove_partials` deletes them.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from ._models import SessionError

PARTIAL_SUFFIX = ".partial"
_HASH_CHUNK = 1 << 20


@dataclass(frozen=True)
class FileDigest:
    """Size and SHA-256 of a file as it was written."""

    sha256: str
    bytes: int


def partial_path(path: Path) -> Path:
    """The temporary name `path` is written under before it is renamed into place."""
    return path.with_name(path.name + PARTIAL_SUFFIX)


def fsync_dir(path: Path) -> None:
    """Make the entries of directory `path` (creations, renames, deletions) durable."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def make_dirs(path: Path) -> None:
    """Create `path` and any missing parents, each made durable in its parent directory.

    Raises FileExistsError if `path` itself already exists, so a directory is never reused.
    """
    missing = [p for p in (path, *path.parents) if not p.exists()]
    if not missing:
        raise FileExistsError(path)
    for directory in reversed(missing):
        directory.mkdir()
        fsync_dir(directory.parent)


def sha256_file(path: Path) -> FileDigest:
    """Hash a file in chunks, so recordings of any size need little memory."""
    digest = hashlib.sha256()
    size = 0
    with path.open("rb") as fh:
        while chunk := fh.read(_HASH_CHUNK):
            digest.update(chunk)
            size += len(chunk)
    return FileDigest(sha256=digest.hexdigest(), bytes=size)


def write_atomic(
    path: Path, fill: Callable[[BinaryIO], object], *, replace: bool = False
) -> FileDigest:
    """Write a file through `<name>.partial`, fsync it, rename it to `path` and fsync the directory.

    `fill` writes the content into the open binary file. Unless `replace` is set, an existing
    `path` is refused, so a completed file is never overwritten; with `replace` the caller is
    the file's one writer, and a `.partial` a crash left is dropped first. If `fill` raises,
    the partial file is removed and the exception propagates.
    """
    if not replace and path.exists():
        raise SessionError(
            f"{path} already exists; choose another name (files are never overwritten)"
        )
    tmp = partial_path(path)
    if replace:
        tmp.unlink(missing_ok=True)
    fh = tmp.open("xb")
    try:
        with fh:
            fill(fh)
            fh.flush()
            os.fsync(fh.fileno())
        digest = sha256_file(tmp)
        os.rename(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(path.parent)
    return digest


def remove_partials(root: Path) -> list[Path]:
    """Delete every `*.partial` file under `root` (left by a crash mid-write); return them."""
    removed = sorted(root.rglob("*" + PARTIAL_SUFFIX))
    for path in removed:
        path.unlink()
    for directory in {path.parent for path in removed}:
        fsync_dir(directory)
    return removed
