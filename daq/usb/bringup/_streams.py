"""The streams of a trace summarised per run: bytes, frames of the enabled channels, the scan.

A run is the data transfers on one stream endpoint of one device between two commands that
start or stop a subsystem (the output stream's run also ends at the next command: the driver
writes the DAC burst before it arms). Its frames follow the guesses: the channels from the
INPUT_CHAN_MASK / OUTPUT_CONTROL writes seen (`ScanSettings.from_registers`), each sample a
`STREAM_DTYPE`; the scan length from SAMPLES_PER_TRIG.
"""

from __future__ import annotations

from typing import Any

from .._ids import EP_STREAM_IN
from .._unpublished import STREAM_DTYPE, Guess, ScanSettings, decode_stream
from ._events import DeviceState, Event, Op, Run
from ._transfer import Status, Transfer

MAX_FIRST_VALUES = 16
"""Codes of the first frame shown."""


def extend_run(dev: DeviceState, tr: Transfer) -> None:
    run = dev.runs.get(tr.endpoint)
    if run is None:
        run = dev.runs[tr.endpoint] = Run(tr.endpoint, tr.t, tr.source)
    run.t_last = tr.t
    run.transfers += 1
    run.length += tr.length
    run.failed += tr.status is not Status.OK
    if not run.first:
        run.first = tr.data


def end_runs(dev: DeviceState, only: int | None = None) -> list[Event]:
    events = []
    for ep in [e for e in dev.runs if only is None or e == only]:
        events.append(_stream_event(dev, dev.runs.pop(ep)))
    return events


def _stream_event(dev: DeviceState, run: Run) -> Event:
    settings = ScanSettings.from_registers(lambda a: dev.registers.get(a, 0))
    is_in = run.endpoint == EP_STREAM_IN
    channels = settings.inputs if is_in else settings.outputs
    where = f"stream {'in' if is_in else 'out'} 0x{run.endpoint:02x}"
    head = f"{where}: {run.transfers} transfers, {run.length} bytes"
    fields: dict[str, Any] = {"endpoint": run.endpoint, "transfers": run.transfers,
                              "bytes": run.length, "t_end": round(run.t_last, 6),
                              "channels": list(channels)}
    presence = Guess.STREAM_DTYPE if is_in else Guess.ARM_COMMANDS
    if not channels:
        return Event(run.t, dev.info.key, "stream", head + " (no channels enabled in the "
                     "registers seen: frames unknown)", run.source, fields,
                     (Op(where, "frames unknown", presence, Guess.STREAM_DTYPE),))
    frame = STREAM_DTYPE.itemsize * len(channels)
    frames, torn = divmod(run.length, frame)
    text = f"{head} = {frames} frames of {len(channels)} channels {list(channels)}"
    verdict = f"{len(channels)}-channel frames, " + ("whole" if not torn else "torn")
    if torn:
        text += f" and {torn} bytes of a torn frame"
    if is_in:
        relation = _against_scan(frames, settings.samples)
        text += f"; the scan: {settings.samples or 'continuous'}" + (
            f" samples ({relation})" if settings.samples else "")
        verdict += f", {relation}"
    first = run.first[: frame * (len(run.first) // frame)][:frame]
    if first:
        codes = decode_stream(first, len(channels))[0][:MAX_FIRST_VALUES]
        fields["first_frame"] = [int(c) for c in codes]
        text += f"; first frame {' '.join(str(int(c)) for c in codes)}"
    if run.failed:
        text += f"; {run.failed} transfers ended early (cancelled or failed)"
    fields.update(frames=frames, torn_bytes=torn)
    return Event(run.t, dev.info.key, "stream", text, run.source, fields,
                 (Op(where, verdict, presence, Guess.STREAM_DTYPE),))


def _against_scan(frames: int, samples: int) -> str:
    if not samples:
        return "continuous scan"
    if frames == samples:
        return "as many frames as the scan's samples"
    return "more frames than the scan's samples" if frames > samples else (
        "fewer frames than the scan's samples")
