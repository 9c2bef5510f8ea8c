"""Files micam installs on a machine: udev rules (udev/) and systemd units (systemd/).

The udev rules live in udev/ at the top of the repository; a built wheel holds them here, as
micam/data/udev/ (setup.py maps them in). `shipped` reads a file from either.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

CHECKOUT_FOLDERS = {"udev": Path(__file__).resolve().parents[2] / "udev"}
"""Where a folder is when micam runs from its repository (a checkout, an editable install)."""


def shipped(folder: str, name: str) -> str:
    """The text of the shipped file `folder/name` (folder: "udev" or "systemd")."""
    packaged = files(__name__).joinpath(folder, name)
    if packaged.is_file() or folder not in CHECKOUT_FOLDERS:
        return packaged.read_text()
    return (CHECKOUT_FOLDERS[folder] / name).read_text()
