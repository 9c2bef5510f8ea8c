"""Every numeric option of every `micam` command has bounds (micam/commands/bounded.py).

The parser is walked, not listed, so that a numeric option added later without a range fails
here. An option counts as numeric when its type turns a number into a number (alone, as a
POSE:SPEAKER pair, or as a size such as 1GiB); it must then refuse what no one means (1e300,
-1e300, a 20-digit integer, nan, inf) with argparse's usage error, unless its choices bound it.
Its default must lie within its range, and an option that fills a model field with a range
of its own must take the same range (the burst's options: tests/acquisition/test_burst.py).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import pytest
from pydantic import BaseModel

from acquisition.contracts.protocol import LiveRecordArgs, LiveStartArgs, SessionStartArgs
from acquisition.contracts.rig_description import KnownAir
from acquisition.daemon.config import WorkersConfig
from micam.cli import build_parser
from micam.commands.bounded import Bounded
from sim.capture import SimulationOptions

SYNTAXES = ("{}", "{}:0", "0:{}", "{}GiB")
"""How a number may be written in an option: alone, in a pair, as a size."""
ABSURD = ("1e300", "-1e300", "9" * 20, "-" + "9" * 20, "nan", "inf", "-inf")


def _options(parser: argparse.ArgumentParser, path: str = "micam"
             ) -> Iterator[tuple[str, argparse.Action]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            seen: set[int] = set()
            for name, sub in action.choices.items():
                if id(sub) not in seen:  # aliases (`inspect session`) once
                    seen.add(id(sub))
                    yield from _options(sub, f"{path} {name}")
        elif action.type is not None:
            yield path, action


OPTIONS = {f"{path} {'/'.join(a.option_strings) or a.dest}": a
           for path, a in _options(build_parser())}


def _is_number(value: object) -> bool:
    if isinstance(value, tuple):
        return bool(value) and all(map(_is_number, value))
    return isinstance(value, int | float) and not isinstance(value, bool)


def _accepts(kind, text: str) -> bool:
    try:
        kind(text)
    except (argparse.ArgumentTypeError, ValueError, TypeError):
        return False
    return True


def test_the_walk_finds_the_options() -> None:
    assert "micam live video --grid" in OPTIONS and "micam worker --cache-max" in OPTIONS
    assert len(OPTIONS) > 100


@pytest.mark.parametrize("name", sorted(OPTIONS))
def test_every_numeric_option_is_bounded(name: str) -> None:
    action = OPTIONS[name]
    if action.choices is not None:
        return  # argparse refuses anything but the choices
    assert callable(action.type)  # not a name of argparse's registry
    for syntax in SYNTAXES:
        try:
            sample = action.type(syntax.format("1"))
        except (argparse.ArgumentTypeError, ValueError, TypeError):
            continue
        if not _is_number(sample):
            continue
        accepted = [v for v in ABSURD if _accepts(action.type, syntax.format(v))]
        assert not accepted, f"{name} accepts {', '.join(map(syntax.format, accepted))}"


@pytest.mark.parametrize("name", sorted(n for n, a in OPTIONS.items()
                                        if isinstance(a.type, Bounded)))
def test_every_default_is_within_its_range(name: str) -> None:
    action = OPTIONS[name]
    default = action.default
    if default is None or isinstance(default, str):  # argparse runs a string through the type
        return
    for value in default if isinstance(default, tuple | list) else (default,):
        assert _accepts(action.type, repr(value)), f"{name}'s default {value} is outside it"


MIRRORED = [
    ("micam simulate --poses", SimulationOptions, "poses"),
    ("micam simulate --temperature", SimulationOptions, "temperature_c"),
    ("micam study --poses", SimulationOptions, "poses"),
    ("micam session start --poses", SessionStartArgs, "poses"),
    ("micam live start --seconds", LiveStartArgs, "seconds"),
    ("micam live start --camera-fps", LiveStartArgs, "camera_fps"),
    ("micam live record --seconds", LiveRecordArgs, "seconds"),
    ("micam worker --heartbeat", WorkersConfig, "heartbeat_interval_s"),
    ("micam calibrate --temperature", KnownAir, "temperature_c"),
    ("micam calibrate --temperature-std", KnownAir, "temperature_std_c"),
    ("micam calibrate --humidity", KnownAir, "relative_humidity"),
    ("micam calibrate --humidity-std", KnownAir, "relative_humidity_std"),
    ("micam calibrate --known-speed-of-sound", KnownAir, "speed_of_sound_m_s"),
    ("micam calibrate --known-speed-of-sound-std", KnownAir, "speed_of_sound_std_m_s"),
]


@pytest.mark.parametrize(("name", "model", "field"), MIRRORED)
def test_an_option_takes_the_range_of_the_field_it_fills(name: str, model: type[BaseModel],
                                                         field: str) -> None:
    bounds = {key: getattr(rule, key) for rule in model.model_fields[field].metadata
              for key in ("ge", "gt", "le") if hasattr(rule, key)}
    option = OPTIONS[name].type
    assert isinstance(option, Bounded)
    above = "gt" in bounds
    lo = bounds["gt"] if above else bounds["ge"]
    expected = (lo + above, bounds["le"], False) if option.parse is int else (lo, bounds["le"],
                                                                               above)
    assert (option.lo, option.hi, option.above) == expected
