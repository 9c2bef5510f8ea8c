"""The base of every configuration section, and a bad configuration described for a person.

Every model a configuration file reaches (the daemon's sections, the capture configuration and
everything nested in it) derives from `ConfigModel`, which refuses unknown keys: a misspelt
option is an error naming the key, never a setting silently ignored. `describe_problems` turns
pydantic's ValidationError into one line per problem that names the key, its section, the keys
the section accepts and the closest one to a misspelling, and, for a field that gives
`examples`, what to write instead (`write e.g. key = value (its description)`).
"""

from __future__ import annotations

import difflib
import json
from typing import Any, get_args

from pydantic import BaseModel, ConfigDict, ValidationError

Loc = tuple[int | str, ...]


class ConfigModel(BaseModel):
    """A configuration section: frozen, and an unknown key is a validation error."""

    model_config = ConfigDict(frozen=True, extra="forbid")


def describe_problems(exc: ValidationError, root: type[BaseModel]) -> list[str]:
    """One line per error of `exc`, raised validating `root`: `path.to.key: what is wrong`."""
    return [_describe(error, root) for error in exc.errors()]


def _describe(error: Any, root: type[BaseModel]) -> str:
    loc: Loc = tuple(error["loc"])
    where = dotted(loc) or "(top level)"
    if error["type"] == "extra_forbidden" and loc:
        key, section = str(loc[-1]), loc[:-1]
        text = f"{where}: unknown key {key!r} {_section_name(section)}"
        model = model_at(root, section)
        if model is not None:
            accepted = list(model.model_fields)
            close = difflib.get_close_matches(key, accepted, n=1)
            if close:
                text += f"; did you mean {close[0]!r}?"
            text += f" (it accepts: {', '.join(accepted)})"
        return text
    message = str(error["msg"]).removeprefix("Value error, ")
    given = error.get("input")
    if error["type"] != "missing" and isinstance(given, str | int | float | bool):
        message += f" (got {given!r})"
    return f"{where}: {message}{_hint(root, loc)}"


def _hint(root: type[BaseModel], loc: Loc) -> str:
    """`; write e.g. key = example (description)` for the field at `loc`, if it has an
    example (in TOML's notation: JSON's lists, strings and numbers are TOML's too)."""
    found = _field_at(root, loc)
    if found is None:
        return ""
    name, field = found
    if not field.examples:
        return ""
    text = f"; write e.g. {name} = {json.dumps(field.examples[0])}"
    return text + (f" ({field.description})" if field.description else "")


def _field_at(root: type[BaseModel], loc: Loc) -> tuple[str, Any] | None:
    """The name and FieldInfo of the last key of `loc` that is a field (list indices and
    union tags skipped), or None."""
    model: type[BaseModel] | None = root
    found = None
    for part in loc:
        if isinstance(part, int) or model is None:
            continue
        field = model.model_fields.get(part)
        if field is None:
            continue
        found = (part, field)
        model = _model_in(field.annotation)
    return found


def dotted(loc: Loc) -> str:
    """`('hardware', 'capture', 'boards', 0, 'serial')` as `hardware.capture.boards[0].serial`."""
    text = ""
    for part in loc:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


def _section_name(section: Loc) -> str:
    return f"in [{dotted(section)}]" if section else "at the top level"


def model_at(root: type[BaseModel], section: Loc) -> type[BaseModel] | None:
    """The model class that validates the table at `section` (list indices and pydantic's
    union tags skipped); None if the path does not lead to a model."""
    model = root
    for part in section:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(part)
        if field is None:
            continue  # a union member's tag, not a key
        inner = _model_in(field.annotation)
        if inner is None:
            return None
        model = inner
    return model


def _model_in(annotation: Any) -> type[BaseModel] | None:
    """The first model class in `annotation` (`X`, `X | None`, `tuple[X, ...]`, …)."""
    found = _models_in(annotation)
    return found[0] if found else None


def models_within(root: type[BaseModel]) -> list[type[BaseModel]]:
    """`root` and every model class reachable through its fields (for checking that each one
    refuses unknown keys)."""
    seen: list[type[BaseModel]] = []
    todo = [root]
    while todo:
        model = todo.pop()
        if model in seen:
            continue
        seen.append(model)
        for field in model.model_fields.values():
            todo.extend(_models_in(field.annotation))
    return seen


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in get_args(annotation) for m in _models_in(arg)]
