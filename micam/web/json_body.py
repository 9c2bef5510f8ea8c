"""JSON from outside the page (a request's body, a session's file), read within bounds.

`load_json` refuses, with a reason for a person (JsonInputError), a text that is longer than
its limit, nested deeper than MAX_DEPTH (counted on the bytes, before the parser recurses), not
UTF-8, not JSON, or holding what the page could not pass on or show: NaN or Infinity (as
constants, or as a number too large for a float), an integer of more than MAX_INT_DIGITS
digits, or a lone UTF-16 surrogate (`"\\ud800"`, which UTF-8 cannot carry).
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

from acquisition.contracts.errors import UserError

MAX_DEPTH = 32
"""Nesting of arrays and objects (a command is 2 deep, a result.json 5)."""
MAX_INT_DIGITS = 19
"""An integer's digits: every integer the page takes fits in 64 bits."""
_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")


class JsonInputError(UserError):
    """A JSON text from outside the page that it does not read (the message says why)."""


def nesting_depth(raw: bytes) -> int:
    """How deep arrays and objects nest in the JSON text `raw` (brackets inside strings do not
    count), without parsing it."""
    brackets = _STRING.sub(b"", raw).translate(None, _NOT_BRACKETS)
    depth = deepest = 0
    for byte in brackets:
        depth += 1 if byte in b"[{" else -1
        deepest = max(deepest, depth)
    return deepest


def _constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON allows")


def _float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"the number {text[:20]} is too large")
    return value


def _int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"an integer of {len(text)} digits is too long")
    return int(text)


def load_json(raw: bytes, max_bytes: int, what: str) -> Any:
    """The JSON value of `raw`; JsonInputError("`what` ...: why") if it is not one the page
    reads (see the module docstring)."""
    if len(raw) > max_bytes:
        raise JsonInputError(f"{what} has {len(raw)} bytes; at most {max_bytes} are read")
    if nesting_depth(raw) > MAX_DEPTH:
        raise JsonInputError(f"{what} nests arrays and objects more than {MAX_DEPTH} deep")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise JsonInputError(f"{what} is not UTF-8 text: {exc.reason} at byte {exc.start}"
                             ) from None
    try:
        value = json.loads(text, parse_constant=_constant, parse_float=_float,
                           parse_int=_int)
        json.dumps(value, ensure_ascii=False).encode("utf-8")
    except UnicodeEncodeError:
        raise JsonInputError(f"{what} holds a lone UTF-16 surrogate (an escape such as "
                             "\\ud800 with no pair)") from None
    except ValueError as exc:
        raise JsonInputError(f"{what} is not JSON the page reads: {exc}") from None
    return value
