"""How the terminal commands show the daemon's status and events: one line per event."""

from __future__ import annotations

import numpy as np

from acquisition.contracts.job_messages import LiveUpdate
from acquisition.contracts.protocol import (
    CalibrationEvent,
    CaptureEvent,
    CheckerboardEvent,
    ErrorEvent,
    Event,
    InstructionEvent,
    JobEvent,
    LevelsEvent,
    LiveCalibrationEvent,
    LiveFrameEvent,
    LiveModeEvent,
    LiveRecordedEvent,
    ProgressEvent,
    StateEvent,
    StatusResult,
    WarningEvent,
    WorkerEvent,
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
        clipped = f", CLIPPED on columns {event.clipped_channels}" if event.clipped_channels else ""
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
    if isinstance(event, LiveCalibrationEvent):
        return format_live(event.update)
    if isinstance(event, CalibrationEvent):
        return (f"CALIBRATED: {event.n_microphones} microphones, mean std "
                f"{event.mean_std_m * 1e3:.3f} mm, c {event.speed_of_sound_m_s:.2f} m/s "
                f"(worker {event.worker}, attempt {event.attempt}) -> {event.path}")
    if isinstance(event, JobEvent):
        if event.state == "failed":
            return f"ERROR calibration job {event.job_id}: {event.reason}"
        who = f" on {event.worker}" if event.worker else ""
        why = f": {event.reason}" if event.reason else ""
        return f"  job {event.job_id} {event.state}{who} (attempt {event.attempt}){why}"
    if isinstance(event, WorkerEvent):
        why = f" ({event.reason})" if event.reason else ""
        return f"worker {event.worker} {event.state}{why}"
    if isinstance(event, LiveModeEvent):
        why = f" ({event.reason})" if event.reason else ""
        return f"live mode {'on' if event.running else 'off'}{why}"
    if isinstance(event, LiveRecordedEvent):
        return (f"live recording {event.path} written" if not event.error
                else f"ERROR live recording {event.path}: {event.error}")
    if isinstance(event, LiveFrameEvent):
        return f"  live frame of {event.camera} at sample {event.sample}"
    return repr(event)  # pragma: no cover - every event type is listed above


def format_live(update: LiveUpdate, target_m: float | None = None) -> str:
    """The live calibration in two lines: how good it is, and where to put the next pose."""
    line = (f"live calibration ({update.poses} poses): mean uncertainty "
            f"{update.mean_uncertainty_m * 1e3:.3f} mm, predicted accuracy "
            f"{update.predicted_accuracy_m * 1e3:.3f} mm, c {update.speed_of_sound_m_s:.2f} m/s")
    if target_m is not None and update.predicted_accuracy_m <= target_m:
        line += (f"\n  TARGET {target_m * 1e3:g} mm REACHED: you may stop "
                 "(`micam session stop`)")
    hint = update.suggestion
    if hint is not None:
        side = "right" if hint.azimuth_deg >= 0 else "left"
        up = "up" if hint.elevation_deg >= 0 else "down"
        line += (f"\n  next pose helps most at {hint.distance_m:.2f} m, "
                 f"{abs(hint.azimuth_deg):.0f} deg {side}, "
                 f"{abs(hint.elevation_deg):.0f} deg {up} "
                 f"(predicted {hint.predicted_accuracy_m * 1e3:.3f} mm)")
    return line


def format_status(status: StatusResult) -> str:
    """A few lines for `micam session status` and the head of `micam watch`."""
    where = "simulated world" if status.simulated else "hardware"
    cal = status.calibration
    lines = [f"state     {status.state} ({where})",
             f"workers   {len(cal.workers)} ({', '.join(w.name for w in cal.workers) or 'none'});"
             f" jobs {cal.pending} pending, {cal.leased} running, {cal.done} done, "
             f"{cal.failed} failed"]
    s = status.session
    if s is None:
        lines.append("session   none (start one with `micam session start`)")
        if status.resumable:
            lines.append(f"resumable {status.resumable} was interrupted: continue it with "
                         f"`micam session start --resume {status.resumable}`")
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
