"""Which events of a trace to keep: one device, one board serial, a time window.

A board's serial is known only once its EEPROM reply has been decoded, a few transfers after
the board appears; until then a device's events are held (at most MAX_HELD per device) and
kept or dropped when the serial shows. A device never identified (an FX2 in loader state) does
not match a serial.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from ._decode import Decoder
from ._events import Event

MAX_HELD = 10_000
"""Events held per device while its serial is unknown; a device past it does not match."""


@dataclass(frozen=True)
class Selection:
    """Attributes (None: no restriction):
        device: "BUS:ADDRESS" as the decoded trace names devices.
        serial: the board serial from the EEPROM.
        start, end: seconds since the first record of the file (inclusive).
    """

    device: str | None = None
    serial: str | None = None
    start: float | None = None
    end: float | None = None


def select(events: Iterable[Event], decoder: Decoder, selection: Selection) -> Iterator[Event]:
    """The events of `selection`, in order; `decoder` is the one producing `events`."""
    held: dict[str, list[Event]] = {}
    rejected: set[str] = set()
    for event in events:
        if selection.device is not None and event.device != selection.device:
            continue
        if not _in_window(event, selection):
            continue
        if selection.serial is None:
            yield event
            continue
        key = event.device
        info = decoder.devices.get(key)
        serial = info.serial if info is not None else None
        if key in rejected:
            continue
        if serial is None:
            queue = held.setdefault(key, [])
            queue.append(event)
            if len(queue) > MAX_HELD:
                rejected.add(key)
                del held[key]
            continue
        if serial != selection.serial:
            rejected.add(key)
            held.pop(key, None)
            continue
        yield from held.pop(key, [])
        yield event


def _in_window(event: Event, selection: Selection) -> bool:
    return ((selection.start is None or event.t >= selection.start)
            and (selection.end is None or event.t <= selection.end))
