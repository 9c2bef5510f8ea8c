"""Checks of the files a command will write, made before the work starts.

A calibration or an imaging run takes minutes; an output that cannot be written must fail at
once with a one-line error, not after the work with a traceback (and half of its outputs
written).
"""

from __future__ import annotations

import os
from pathlib import Path

from acquisition.contracts.errors import UserError


def check_outputs(*outputs: tuple[str, Path | None]) -> None:
    """UserError naming the option when an output (`(flag, path)`, None: not asked for) cannot
    be written: its directory is missing or read-only, or the path is a directory."""
    for flag, path in outputs:
        if path is None:
            continue
        parent = path.absolute().parent
        if not parent.is_dir():
            raise UserError(f"the directory of {flag} ({parent}) does not exist; create it "
                            "first")
        if path.is_dir():
            raise UserError(f"{flag} {path} is a directory; name a file")
        if not os.access(parent, os.W_OK):
            raise UserError(f"{flag}: cannot write in {parent} (no permission)")
