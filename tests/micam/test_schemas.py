"""The shipped JSON Schemas are the models' own: regenerated, they match the files."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from micam import schemas

REPO = Path(__file__).resolve().parents[2]


def test_the_shipped_schemas_are_the_models_schemas() -> None:
    generated = {name: schemas.render(s) for name, s in schemas.generate().items()}
    shipped = schemas.shipped()
    assert sorted(shipped) == sorted(generated), "run `python -m micam.schemas`"
    stale = [name for name in generated if shipped[name] != generated[name]]
    assert not stale, f"stale schemas {stale}: run `python -m micam.schemas`"


def test_every_document_kind_has_a_schema() -> None:
    names = set(schemas.shipped())
    assert {"session-manifest", "journal-record", "capture-config", "rig-description",
            "result", "request", "reply", "event", "worker-message", "daemon-message"} <= names
    journal = json.loads(schemas.shipped()["journal-record"])
    kinds = {v["properties"]["kind"]["const"] for v in journal["$defs"].values()
             if "kind" in v.get("properties", {})}
    assert {"session_start", "step_begin", "file", "step_end", "session_stop"} <= kinds


def test_the_wheel_ships_them() -> None:
    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "*.schema.json" in data["package-data"]["micam.schemas"]
