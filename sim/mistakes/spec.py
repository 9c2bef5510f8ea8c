"""The mistakes the simulated world can make: their names, their arguments and what they mean.

A mistake is asked for as `NAME` or `NAME=ARG,ARG,...` (`micam simulate --mistake`, or the
daemon's `[simulation] mistakes`). The arguments are positional and each may be left out from
the right; a missing one is drawn from the session's seed (sim.mistakes.planner). This module
checks what needs no world: the name, the number of arguments, their types and bounds. The
planner checks the rest (that a microphone, speaker, pose or camera exists, that two mistakes
do not contradict). Every failure is a `SimulationInputError` with a one-line message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import SimulationInputError


@dataclass(frozen=True)
class Param:
    """One positional argument: its name in the usage, its type and its bounds (inclusive,
    or exclusive where `open_low` / `open_high`); `repeats`: the last argument may be given
    any number of times."""

    name: str
    integer: bool
    low: float
    high: float = math.inf
    open_low: bool = False
    open_high: bool = False
    repeats: bool = False

    def parse(self, text: str, context: str) -> int | float:
        """The argument `text` as a number within the bounds; SimulationInputError (its
        message starting with `context`) if it is not one."""
        try:
            value: int | float = int(text) if self.integer else float(text)
        except ValueError:  # only the conversion of this one string
            value = math.nan
        below = value <= self.low if self.open_low else value < self.low
        above = value >= self.high if self.open_high else value > self.high
        if not math.isfinite(value) or below or above:
            what = "an integer" if self.integer else "a number"
            raise SimulationInputError(f"{context}: {self.name} must be {what} with "
                                       f"{self.bounds()}, not {text!r}")
        return value

    def bounds(self) -> str:
        low = f"{self.low:g} {'<' if self.open_low else '<='} {self.name}"
        if math.isinf(self.high):
            return low
        return f"{low} {'<' if self.open_high else '<='} {self.high:g}"


MIC = Param("MIC", True, 0)
SPEAKER = Param("SPEAKER", True, 0)
POSE = Param("POSE", True, 0)
CAMERA = Param("CAMERA", True, 0)


@dataclass(frozen=True)
class MistakeKind:
    """A kind of mistake: its name, its arguments and one line of help (`micam simulate
    --help`; docs/simulation.md, "Mistakes", says exactly what each does)."""

    name: str
    params: tuple[Param, ...]
    help: str

    @property
    def usage(self) -> str:
        """How to write it: "swap-mics[=MIC,MIC]"."""
        if not self.params:
            return self.name
        names = [p.name + ("..." if p.repeats else "") for p in self.params]
        return f"{self.name}[={','.join(names)}]"


KINDS: tuple[MistakeKind, ...] = (
    MistakeKind("swap-mics", (MIC, MIC),
                "two microphone cables swapped (default: neighbours on one board)"),
    MistakeKind("board-shift", (Param("BOARDS", True, -8, 8),),
                "the column map off by BOARDS boards (default 1)"),
    MistakeKind("swap-speakers", (SPEAKER, SPEAKER),
                "two speaker cables swapped (default: the two of one board)"),
    MistakeKind("silent-speaker", (SPEAKER, Param("POSE", True, 0, repeats=True)),
                "a speaker that does not play (all session, or at the POSEs)"),
    MistakeKind("inverted-mic", (MIC,), "a microphone wired with inverted polarity"),
    MistakeKind("dead-mic", (MIC,), "a dead microphone: its channel holds only idle noise"),
    MistakeKind("intermittent-mic", (MIC, Param("FRACTION", False, 0, 1, open_low=True)),
                "dropouts to idle noise in FRACTION of its pose recordings (0.3)"),
    MistakeKind("moved-pose", (POSE, Param("MM", False, 0, 100, open_low=True),
                               Param("DEG", False, 0, 30)),
                "the rig nudged after a pose's images (default 5-20 mm, 1-3 deg)"),
    MistakeKind("hidden-board", (POSE, CAMERA, Param("FRACTION", False, 0.05, 0.9)),
                "an arm hiding FRACTION of the board's corners (default 0.3-0.6)"),
    MistakeKind("motion-blur", (POSE, CAMERA, Param("PX", False, 1, 100)),
                "the board blurred by motion over PX pixels (default 8-25)"),
    MistakeKind("glare", (POSE, CAMERA, Param("PX", False, 2, 400)),
                "a highlight saturating a disc of PX pixels radius on the board"),
    MistakeKind("mjpeg", (Param("QUALITY", True, 1, 100),),
                "every camera delivers MJPEG at QUALITY (default 70-90)"),
    MistakeKind("clipped-bursts", (Param("FRACTION", False, 0, 1, open_low=True, open_high=True),
                                   Param("COUNT", True, 1)),
                "COUNT mics nearest the speaker clip at FRACTION of the peak (4, 0.35)"),
    MistakeKind("distorted-speaker", (SPEAKER, Param("DRIVE", False, 0, 20, open_low=True)),
                "a speaker in tanh saturation, peak DRIVE x its limit (default 3)"),
    MistakeKind("refmic-far", (SPEAKER, Param("MM", False, 0, 50, open_low=True)),
                "the reference mic MM mm from a speaker, not as stated (default 6)"),
    MistakeKind("close-reflector", (MIC, Param("US", False, 0, 100, open_low=True),
                                    Param("GAIN", False, -1, 1, open_low=True, open_high=True)),
                "a second path US us after the direct sound, GAIN x it (10-20, 0.3-0.5)"),
)
BY_NAME = {k.name: k for k in KINDS}


@dataclass(frozen=True)
class MistakeSpec:
    """One mistake as asked for: its kind and the arguments given (the others are drawn)."""

    text: str
    kind: MistakeKind
    args: tuple[int | float, ...]

    def arg(self, index: int) -> int | float | None:
        """The argument at `index`, or None when it was not given."""
        return self.args[index] if index < len(self.args) else None


def parse_mistake(text: str) -> MistakeSpec:
    """`NAME[=ARG,...]` checked against its kind's arguments (SimulationInputError if wrong)."""
    name, sep, rest = text.strip().partition("=")
    kind = BY_NAME.get(name.strip())
    if kind is None:
        raise SimulationInputError(
            f"unknown mistake {name.strip()!r} in {text!r}; choose one of "
            f"{', '.join(BY_NAME)} (`micam simulate --help` says what each does)")
    fields = [f.strip() for f in rest.split(",")] if sep else []
    if sep and not all(fields):
        raise SimulationInputError(f"mistake {text!r} has an empty argument; write "
                                   f"{kind.usage}")
    repeats = bool(kind.params) and kind.params[-1].repeats
    if len(fields) > len(kind.params) and not repeats:
        raise SimulationInputError(
            f"mistake {text!r} has {len(fields)} arguments, {kind.name} takes at most "
            f"{len(kind.params)}; write {kind.usage}")
    context = f"mistake {text.strip()!r} ({kind.usage})"
    args = tuple(kind.params[min(i, len(kind.params) - 1)].parse(field, context)
                 for i, field in enumerate(fields))
    return MistakeSpec(text.strip(), kind, args)
