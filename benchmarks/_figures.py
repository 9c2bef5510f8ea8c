"""The end of every benchmark: print its figures, one per line, and write them as JSON."""

from __future__ import annotations

import json
from pathlib import Path


def report(figures: dict, out: Path, width: int = 32) -> None:
    """Print `figures` (name, value) and write them to `out` (JSON, its directory made)."""
    for key, value in figures.items():
        print(f"{key:{width}s} {value}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(figures, indent=2) + "\n")
    print(f"written to {out}")
