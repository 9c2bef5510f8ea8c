"""Who on this machine can reach the daemon's ipc sockets: the daemon decides, not the umask.

An ipc socket is a file: connecting needs write permission on it, and reaching it needs
execute permission on its directory. So the daemon

- creates its default runtime directory (`endpoints.default_runtime_dir`) with mode 0750,
  whatever the umask, and refuses one that is a symbolic link or belongs to another user;
- refuses an ipc socket in a directory that other users may enter or that someone else may
  write to: between `bind` (which creates the file with the umask's mode) and the `chmod`
  after it, only such a directory keeps strangers out, and it stops anyone from replacing the
  socket file;
- sets every socket file's mode itself (`sockets.ipc_mode`, 0660 by default: the daemon's
  user and group may connect).

Abstract sockets (`ipc://@name`) and loopback TCP have no permissions at all; security.py
refuses them without CURVE (or, for loopback TCP, an explicit opt-in).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import zmq

from .config import ConfigError
from .endpoints import default_runtime_dir, ipc_path

RUNTIME_DIR_MODE = 0o750


def prepare_runtime_dir(directory: Path) -> None:
    """Create the default runtime directory with mode 0750, or check and re-mode it."""
    try:
        directory.mkdir(mode=RUNTIME_DIR_MODE, parents=True, exist_ok=True)
        info = os.lstat(directory)
    except OSError as exc:
        raise ConfigError(f"cannot create the runtime directory {directory}: {exc}; set "
                          "MICAM_RUNTIME_DIR to a directory of yours") from None
    if not stat.S_ISDIR(info.st_mode):
        raise ConfigError(f"the runtime directory {directory} is not a directory (a symbolic "
                          "link?); remove it or set MICAM_RUNTIME_DIR elsewhere")
    if info.st_uid != os.getuid():
        raise ConfigError(f"the runtime directory {directory} belongs to user {info.st_uid}, "
                          "not to the daemon's user; remove it or set MICAM_RUNTIME_DIR")
    os.chmod(directory, RUNTIME_DIR_MODE)


def check_socket_directory(directory: Path) -> None:
    """Refuse a directory for ipc sockets that strangers could enter or write (see above)."""
    try:
        info = os.stat(directory)
    except OSError as exc:
        raise ConfigError(f"the directory of the ipc socket, {directory}, is not usable: "
                          f"{exc}; create it (mode 0750) first") from None
    mine = info.st_uid in (os.getuid(), 0)
    if not mine or info.st_mode & (stat.S_IWGRP | stat.S_IWOTH | stat.S_IXOTH):
        raise ConfigError(
            f"refusing an ipc socket in {directory} (mode {stat.S_IMODE(info.st_mode):04o}, "
            f"owner {info.st_uid}): other users could reach or replace it. Use a directory of "
            "the daemon's user with mode 0750 or 0700, such as the default runtime directory "
            f"{default_runtime_dir()} (docs/security.md)")


def bind_local(sock: zmq.Socket, endpoint: str, ipc_mode: int) -> None:
    """Bind `sock` to `endpoint`; an ipc socket file then gets `ipc_mode` (see above)."""
    path = ipc_path(endpoint)
    if path is None:
        sock.bind(endpoint)
        return
    if path.parent == default_runtime_dir():
        prepare_runtime_dir(path.parent)
    check_socket_directory(path.parent)
    sock.bind(endpoint)
    os.chmod(path, ipc_mode)
