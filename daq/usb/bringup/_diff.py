"""Two traces compared: aligned by their command sequence, every difference named.

Typically A is Data Translation's software captured with usbmon or USBPcap and B is micam
doing the same scan (its `TransferTrace`, or a capture of it). Each trace is decoded
(`_decode`), its boards paired (by EEPROM serial, then in order of appearance), and each
board's steps (`Op`s: one per register read or write, command, message, firmware segment or
stream run) aligned with difflib's SequenceMatcher over their keys. Then:

- steps that align but carry different values: a different register value, ExtTrig flag,
  reply length or stream framing ("12-channel frames, torn, more frames than the scan's
  samples");
- steps only in A (missing in B) or only in B (extra in B);
- boards only in one trace, or with different product ids.

Each difference names what it contradicts: a `Guess` of daq/usb/_unpublished.py (the basis
of the step, or of its value), or the public fact or micam choice it rests on.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from difflib import SequenceMatcher
from pathlib import Path
from typing import Any

from .._families import DT9816
from .._unpublished import Guess
from ._decode import Decoder
from ._events import DeviceInfo, Event, Op
from ._errors import TraceError
from ._read import read_transfers
from ._select import Selection, select

MAX_STEPS = 100_000
"""Steps aligned per board; SequenceMatcher's time grows with the product of two lengths."""

UNPUBLISHED = "daq/usb/_unpublished.py"
_GUESSES = {g.value for g in Guess}


@dataclass(frozen=True)
class Step:
    op: Op
    event: Event


@dataclass
class Board:
    """One board of one trace: what the trace tells about it, and its steps."""

    info: DeviceInfo
    steps: list[Step] = field(default_factory=list)


@dataclass(frozen=True)
class Difference:
    """One difference between trace A and trace B.

    Attributes:
        kind: "value" (aligned steps, different values), "missing" (in B), "extra" (in B),
            "board" (a board or its identity).
        key: the step ("write MISC_CTRLS", "stream in 0x82", "board serial 3").
        a, b: A's and B's value (None where the step is absent).
        step_a, step_b: the events in A and B (None where absent); for a missing or extra
            step, the neighbouring step of the other trace, for its place.
        bases: what the difference contradicts (guess names of `_unpublished` first).
        boards: the paired boards' labels, A's and B's.
    """

    kind: str
    key: str
    a: str | None
    b: str | None
    step_a: Event | None
    step_b: Event | None
    bases: tuple[str, ...]
    boards: tuple[str, str]

    @property
    def guesses(self) -> tuple[str, ...]:
        return tuple(b for b in self.bases if b in _GUESSES)

    def text(self) -> str:
        where = f"[{self.boards[0]} | {self.boards[1]}]"
        if self.kind == "value":
            what = f"{self.key}: {self.a} in A ({_at(self.step_a)}), {self.b} in B " \
                   f"({_at(self.step_b)})"
        elif self.kind == "missing":
            what = f"missing in B: {self.key} = {self.a} (A {_at(self.step_a)}; B near " \
                   f"{_at(self.step_b)})"
        elif self.kind == "extra":
            what = f"extra in B: {self.key} = {self.b} (B {_at(self.step_b)}; A near " \
                   f"{_at(self.step_a)})"
        else:
            what = f"{self.key}: {self.a or 'absent'} in A, {self.b or 'absent'} in B"
        return f"{where} {what} -- {_contradicts(self.bases)}"

    def as_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "key": self.key, "a": self.a, "b": self.b,
                "a_record": None if self.step_a is None else self.step_a.source,
                "b_record": None if self.step_b is None else self.step_b.source,
                "a_t": None if self.step_a is None else round(self.step_a.t, 6),
                "b_t": None if self.step_b is None else round(self.step_b.t, 6),
                "contradicts": [b for b in self.bases if b in _GUESSES],
                "rests_on": [b for b in self.bases if b not in _GUESSES],
                "boards": list(self.boards)}


@dataclass(frozen=True)
class TraceDiff:
    """The differences of trace B from trace A."""

    a: Path
    b: Path
    pairs: tuple[tuple[str, str], ...]
    differences: tuple[Difference, ...]

    def summary(self) -> dict[str, int]:
        """How many differences contradict each guess (and rest on each other basis)."""
        counts: dict[str, int] = {}
        for d in self.differences:
            for basis in d.bases:
                counts[basis] = counts.get(basis, 0) + 1
        return dict(sorted(counts.items(), key=lambda kv: (kv[0] not in _GUESSES, kv[0])))


def diff_traces(a: Path, b: Path, serial: str | None = None) -> TraceDiff:
    """Compare the traces at `a` and `b` (any format `read_transfers` reads)."""
    boards_a, boards_b = _boards(a, serial), _boards(b, serial)
    for path, boards in ((a, boards_a), (b, boards_b)):
        if not boards:
            which = f"with serial {serial} " if serial is not None else ""
            raise TraceError(f"{path} has no board {which}with commands to compare; "
                             "`micam daq trace show` lists its devices")
    pairs, differences = [], []
    for board_a, board_b in _pair(boards_a, boards_b):
        labels = (board_a.info.label() if board_a else "-", board_b.info.label() if board_b
                  else "-")
        pairs.append(labels)
        if board_a is None or board_b is None:
            present = board_a or board_b
            assert present is not None
            differences.append(Difference(
                "board", f"board {present.info.label()}",
                labels[0] if board_a else None, labels[1] if board_b else None,
                None, None, ("the boards in the traces",), labels))
            continue
        differences += _identity(board_a, board_b, labels)
        differences += _align(board_a.steps, board_b.steps, labels)
    return TraceDiff(a, b, tuple(pairs), tuple(differences))


def _boards(path: Path, serial: str | None) -> list[Board]:
    decoder = Decoder()

    def events() -> Iterable[Event]:
        for tr in read_transfers(path):
            yield from decoder.feed(tr)
        yield from decoder.finish()

    boards: dict[str, Board] = {}
    for event in select(events(), decoder, Selection(serial=serial)):
        if not event.ops:
            continue
        board = boards.setdefault(event.device, Board(DeviceInfo(event.device)))
        board.steps += [Step(op, event) for op in event.ops]
        if len(board.steps) > MAX_STEPS:
            raise TraceError(f"{path}: device {event.device} has more than {MAX_STEPS} steps "
                             "to align; compare shorter traces (one scan each)")
    for key, board in boards.items():
        board.info = decoder.devices[key]
    return list(boards.values())


def _pair(a: list[Board], b: list[Board]) -> list[tuple[Board | None, Board | None]]:
    """Boards with the same serial, then the rest in order of appearance."""
    by_serial = {x.info.serial: x for x in b if x.info.serial is not None}
    pairs: list[tuple[Board | None, Board | None]] = []
    rest_a, used = [], set()
    for x in a:
        match = by_serial.get(x.info.serial) if x.info.serial is not None else None
        if match is not None and id(match) not in used:
            pairs.append((x, match))
            used.add(id(match))
        else:
            rest_a.append(x)
    rest_b = [y for y in b if id(y) not in used]
    for i in range(max(len(rest_a), len(rest_b))):
        pairs.append((rest_a[i] if i < len(rest_a) else None,
                      rest_b[i] if i < len(rest_b) else None))
    return pairs


def _identity(a: Board, b: Board, labels: tuple[str, str]) -> list[Difference]:
    pa, pb = a.info.product_id, b.info.product_id
    if pa is None or pb is None or pa == pb:
        return []
    dt9816 = DT9816.loader_pid in (pa, pb) or DT9816.running_pid in (pa, pb) or (
        a.info.model or "").startswith("DT9816")
    basis = Guess.DT9816_RUNNING_PID if dt9816 else "public: the USB ids (daq/usb/_ids.py)"
    return [Difference("board", "product id", f"0x{pa:04x}", f"0x{pb:04x}", None, None,
                       (basis,), labels)]


def _align(a: list[Step], b: list[Step], labels: tuple[str, str]) -> list[Difference]:
    matcher = SequenceMatcher(None, [s.op.key for s in a], [s.op.key for s in b],
                              autojunk=False)
    out: list[Difference] = []
    for tag, i1, i2, j1, j2 in matcher.get_opcodes():
        if tag == "equal":
            for sa, sb in zip(a[i1:i2], b[j1:j2], strict=True):
                if sa.op.value != sb.op.value:
                    out.append(Difference("value", sa.op.key, sa.op.value, sb.op.value,
                                          sa.event, sb.event,
                                          _bases(sa.op.value_basis, sb.op.value_basis),
                                          labels))
            continue
        near_b = b[j1].event if j1 < len(b) else (b[-1].event if b else None)
        near_a = a[i1].event if i1 < len(a) else (a[-1].event if a else None)
        out += [Difference("missing", s.op.key, s.op.value, None, s.event, near_b,
                           (s.op.basis,), labels) for s in a[i1:i2]]
        out += [Difference("extra", s.op.key, None, s.op.value, near_a, s.event,
                           (s.op.basis,), labels) for s in b[j1:j2]]
    return out


def _bases(*bases: str) -> tuple[str, ...]:
    unique = list(dict.fromkeys(bases))
    return tuple(sorted(unique, key=lambda x: x not in _GUESSES))


def _at(event: Event | None) -> str:
    return "-" if event is None else f"record {event.source}, {event.t:.6f} s"


def _contradicts(bases: tuple[str, ...]) -> str:
    guesses = [b for b in bases if b in _GUESSES]
    others = [b for b in bases if b not in _GUESSES]
    parts = []
    if guesses:
        parts.append(f"contradicts {UNPUBLISHED}: {', '.join(guesses)}")
    if others:
        parts.append(f"rests on {'; '.join(others)}")
    return "; ".join(parts)
