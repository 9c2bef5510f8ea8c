"""JSON Schemas of every document micam writes or sends, generated from its pydantic models and
shipped in the wheel (micam/schemas/*.schema.json), for readers in any language.

The documents: the session manifest and journal records (docs/session-format.md), the capture
and rig description (the capture configuration in the manifest, the rig and array description
of an imported session), result.json, and the messages of the daemon's protocol and the
calibration hand-off (docs/protocol.md). `python -m micam.schemas` writes them again after a
model changed; tests/micam/test_schemas.py fails while the shipped files differ from the models.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from pydantic import TypeAdapter

HERE = Path(__file__).resolve().parent


def generate() -> dict[str, dict]:
    """Every schema, by file stem."""
    from acquisition.contracts.capture_config import CaptureConfig
    from acquisition.contracts.protocol import json_schemas
    from acquisition.contracts.rig_description import RigDescription
    from acquisition.contracts.session import Record, SessionManifest
    from calibration.result import CalibrationResult

    return {
        "session-manifest": SessionManifest.model_json_schema(),
        "journal-record": TypeAdapter(Record).json_schema(),
        "capture-config": CaptureConfig.model_json_schema(),
        "rig-description": RigDescription.model_json_schema(),
        "result": CalibrationResult.model_json_schema(),
        **json_schemas(),
    }


def render(schema: dict) -> str:
    """A schema as its shipped file holds it (sorted keys: stable diffs)."""
    return json.dumps(schema, indent=2, sort_keys=True) + "\n"


def shipped() -> dict[str, str]:
    """The shipped files' texts, by file stem."""
    return {p.name.removesuffix(".schema.json"): p.read_text()
            for p in sorted(HERE.glob("*.schema.json"))}


def write(directory: Path = HERE) -> list[Path]:
    """Write every schema into `directory` (default: the package's own), dropping stale ones."""
    schemas = generate()
    for old in directory.glob("*.schema.json"):
        if old.name.removesuffix(".schema.json") not in schemas:
            old.unlink()
    return write_schemas(directory, schemas)


def write_schemas(directory: Path, schemas: Mapping[str, dict]) -> list[Path]:
    """Write `schemas` (by file stem) into `directory` as NAME.schema.json (`render`), creating
    it; other files there are left alone. The files written, in order."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, schema in schemas.items():
        path = directory / f"{name}.schema.json"
        path.write_text(render(schema))
        paths.append(path)
    return paths
