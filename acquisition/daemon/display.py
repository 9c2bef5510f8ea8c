"""How the terminal commands show the daemon's status and events: one line per event."""

from __future__ import annotations

import numpy as np

from .protocol import (
    CaptureEvent,
    CheckerboardEvent,
    ErrorEvent,
    Event,
    InstructionEvent,
    LevelsEvent,
    ProgressEvent,
    StateEvent,
    StatusResult,
    WarningEvent,
)


def _span(values: list[float]) -> str:
    if not values:
        return "n/a"
    return f"{min(values):.0f}..{max(values):.0f} (median {float(np.median(values)):.0f})"


def format_event(event: Event) -> str:
    """One readable line for an event."""
    if isinstance(event, ProgressEvent):
        width = 20
        filled = round(width * event.steps_done / max(event.steps_total, 1))
        return (f"[{'#' * filled}{'.' * (width - filled)}] {event.steps_done}/"
                f"{event.steps_total} steps, {event.poses_done}/{event.n_poses} poses "
                f"(done: {event.step})")
    if isinstance(event, LevelsEvent):
        clipped = f", CLIPPED on {event.clipped_channels}" if event.clipped_channels else ""
        return (f"  {event.step} {event.file}: rms {_span(event.rms_dbfs)} dBFS, peak max "
                f"{max(event.peak_dbfs):.0f} dBFS, SNR {_span(event.snr_db)} dB{clipped}")
    if isinstance(event, CheckerboardEvent):
        found = "found" if event.found else "NOT found"
        return f"  {event.step} {event.camera}: checkerboard {found}"
    if isinstance(event, InstructionEvent):
        return f"next: {event.step}: {event.text}"
    if isinstance(event, StateEvent):
        return f"state: {event.state} ({event.reason})"
    if isinstance(event, CaptureEvent):
        why = f": {event.reason}" if event.reason else ""
        return f"{event.step} {event.outcome}{why}"
    if isinstance(event, WarningEvent):
        return f"WARNING {event.step or ''} {event.check or ''}: {event.message}"
    if isinstance(event, ErrorEvent):
        return f"ERROR {event.step or ''}: {event.message}"
    return repr(event)  # pragma: no cover - every event type is listed above


def format_status(status: StatusResult) -> str:
    """A few lines for `micam session status` and the head of `micam watch`."""
    where = "simulated world" if status.simulated else "hardware"
    lines = [f"state     {status.state} ({where})"]
    s = status.session
    if s is None:
        lines.append("session   none (start one with `micam session start`)")
        return "\n".join(lines)
    lines += [f"session   {s.id} at {s.path}",
              f"progress  {s.steps_done}/{s.steps_total} steps, {s.poses_done}/{s.n_poses} poses"]
    if status.step:
        lines.append(f"step      {status.step}: {status.instruction or ''}")
    last = status.last_capture
    if last is not None:
        extra = last.reason or "; ".join(last.warnings)
        lines.append(f"last      capture {last.number}: {last.step} {last.outcome}"
                     + (f" ({extra})" if extra else ""))
    return "\n".join(lines)
