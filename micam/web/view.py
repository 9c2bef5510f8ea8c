"""What the operator's page shows, made from the daemon's messages.

Pure functions of the protocol's models (acquisition.contracts.protocol): the levels named by
microphone id and board with the reference microphone apart and the flagged channels by name,
each camera's pose count with a warning while it is on course to stay uncalibrated, the live
calibration's microphones with their uncertainty, and the summary of a final result. The
browser only draws what these return. The calibrations come from messages and files, so
their views validate what they read (ViewError names what cannot be shown, never a crash), and
nothing they return holds a number JSON cannot carry (NaN, Infinity).
"""

from __future__ import annotations

import math
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, ValidationError

from acquisition.contracts.capture_config import column_name
from acquisition.contracts.config_model import describe_problems
from acquisition.contracts.errors import UserError
from acquisition.contracts.job_messages import LiveUpdate
from acquisition.contracts.protocol import CameraPoses, DescribeResult, LevelsEvent

ModelT = TypeVar("ModelT", bound=BaseModel)


def channel_name(describe: DescribeResult, column: int) -> str:
    """How a person names a column: "mic 12 (board S1 ch 3)" or "reference mic (board ...)"."""
    if not 0 <= column < len(describe.columns):
        return f"column {column}"
    c = describe.columns[column]
    return column_name(c.role, c.mic_id, c.board, c.channel)


def _value(values: list[float], j: int) -> float | None:
    return values[j] if j < len(values) else None


def levels_view(event: LevelsEvent, describe: DescribeResult) -> dict[str, Any]:
    """One recording's levels: a meter per channel grouped by board, the reference microphone
    apart, and the clipped, dead and low-SNR channels by name."""
    clipped = set(event.clipped_channels)
    dead = set(event.dead_channels)
    low = set(event.low_snr_channels)
    listening = set(event.listening)

    def meter(j: int) -> dict[str, Any]:
        c = describe.columns[j]
        flags = [name for name, on in (("clipped", j in clipped), ("dead", j in dead),
                                       ("low SNR", j in low)) if on]
        return {"column": j, "label": "ref" if c.role == "reference" else str(c.mic_id),
                "name": channel_name(describe, j), "board": c.board,
                "rms_dbfs": _value(event.rms_dbfs, j), "peak_dbfs": _value(event.peak_dbfs, j),
                "snr_db": _value(event.snr_db, j), "listening": j in listening,
                "flags": flags}

    columns = range(min(len(describe.columns), len(event.rms_dbfs)))
    boards: dict[str, list[dict[str, Any]]] = {}
    reference = None
    for j in columns:
        if describe.columns[j].role == "reference":
            reference = meter(j)
        else:
            boards.setdefault(describe.columns[j].board, []).append(meter(j))
    return {
        "step": event.step, "file": event.file, "reference": reference,
        "boards": [{"board": b, "channels": channels} for b, channels in boards.items()],
        "flagged": {"clipped": [channel_name(describe, j) for j in sorted(clipped)],
                    "dead": [channel_name(describe, j) for j in sorted(dead)],
                    "low_snr": [channel_name(describe, j) for j in sorted(low)]},
    }


def camera_warning(views: int, views_left: int, poses_seen: int, poses_done: int,
                   min_views: int) -> str | None:
    """Why a camera is on course to stay uncalibrated, or None.

    `views` are the board views its calibration gets so far (the poses' and the refmic
    image's), `views_left` the steps still to capture that may add one. It cannot be
    calibrated when even a board in every one of them leaves it short of `min_views`; it is
    on course to stay uncalibrated when it keeps finding the board at the rate so far
    (`poses_seen` of `poses_done` poses) and ends the session short of `min_views`.
    """
    if views >= min_views:
        return None
    if views + views_left < min_views:
        return (f"cannot be calibrated: {views} of {min_views} board views needed, and "
                f"only {views_left} left to capture")
    if poses_done == 0:
        return None
    projected = views + views_left * poses_seen / poses_done
    if projected < min_views:
        return (f"on course to stay uncalibrated: the board was seen in {poses_seen} of "
                f"{poses_done} poses; it needs {min_views} views (hold the board in its view)")
    return None


def cameras_view(describe: DescribeResult, seen: list[CameraPoses], poses_done: int,
                 n_poses: int) -> list[dict[str, Any]]:
    """Every camera with its board views so far and its warning (if any). A daemon that does
    not count views (`board_views` None) is judged on its poses alone."""
    by_name = {c.camera: c for c in seen}
    cameras = []
    for name in describe.cameras:
        c = by_name.get(name, CameraPoses(camera=name, poses_seen=0))
        views = c.poses_seen if c.board_views is None else c.board_views
        left = max(0, n_poses - poses_done) if c.views_left is None else c.views_left
        cameras.append({"camera": name, "poses_seen": c.poses_seen, "board_views": views,
                        "warning": camera_warning(views, left, c.poses_seen, poses_done,
                                                  describe.camera_min_views)})
    return cameras


class ViewError(UserError):
    """A calibration (a message or a session's file) the page cannot show; the message says
    why, for the page to show instead."""


class _Lenient(BaseModel):
    """What a view reads of a document, ignoring the rest."""

    model_config = ConfigDict(extra="ignore", frozen=True)


Vector = tuple[FiniteFloat, FiniteFloat, FiniteFloat]


class _ResultMicrophone(_Lenient):
    id: int
    board: str | None = None
    position_m: Vector
    std_m: Vector


class _ResultCamera(_Lenient):
    name: str | None = None


class _Residuals(_Lenient):
    rms_s: FiniteFloat | None = None


class _ShownResult(_Lenient):
    """The parts of a result.json (calibration.result.CalibrationResult) the report shows."""

    session_id: str | None = None
    method: str | None = None
    microphones: list[_ResultMicrophone] = Field(max_length=100_000)
    speed_of_sound_m_s: FiniteFloat
    speed_of_sound_std_m_s: FiniteFloat | None = None
    poses: list[Any] = Field(default=[], max_length=100_000)
    cameras: list[_ResultCamera] = Field(default=[], max_length=1000)
    residuals: _Residuals | None = None


class HistoryPoint(_Lenient):
    """One line of a session's live history (poses, the accuracies in metres, c in m/s)."""

    poses: int = Field(ge=0, le=1_000_000)
    predicted_accuracy_m: FiniteFloat
    mean_uncertainty_m: FiniteFloat
    speed_of_sound_m_s: FiniteFloat


def _validated(model: type[ModelT], data: Any, what: str) -> ModelT:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ViewError(f"this {what} cannot be shown: "
                        f"{describe_problems(exc, model)[0]}") from None


def _require_finite(value: Any, what: str, where: str = "") -> None:
    """ViewError if a number anywhere in `value` is NaN or infinite (JSON has no such numbers:
    the browser could not read the page's message)."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ViewError(f"this {what} cannot be shown: {where or 'it'} is {value}")
    if isinstance(value, dict):
        for key, item in value.items():
            _require_finite(item, what, f"{where}.{key}".lstrip("."))
    elif isinstance(value, list | tuple):
        for n, item in enumerate(value):
            _require_finite(item, what, f"{where}.{n}".lstrip("."))


def _norm(v: tuple[float, float, float]) -> float:
    return math.sqrt(sum(x * x for x in v))


def live_view(update: Any, target_m: float | None) -> dict[str, Any]:
    """The live calibration (a LiveUpdate, or its JSON from a session's live.json) for drawing:
    microphones with their uncertainty (norm of their std, metres), the figures, and whether
    the predicted accuracy meets `target_m`; ViewError if it is not one that can be shown."""
    model = _validated(LiveUpdate, update, "live calibration")
    data = model.model_dump(exclude={"v", "microphones"})
    data["microphones"] = [{"id": m.id, "position_m": list(m.position_m),
                            "uncertainty_m": _norm(m.std_m)} for m in model.microphones]
    data["enough"] = target_m is not None and model.predicted_accuracy_m <= target_m
    _require_finite(data, "live calibration")
    return data


def history_point(data: Any) -> dict[str, Any]:
    """One point of the live calibration's history (LiveUpdate, or a line of the history
    file); ViewError if it is not one that can be shown."""
    if isinstance(data, LiveUpdate):
        data = data.model_dump()
    return _validated(HistoryPoint, data, "live history point").model_dump()


def result_view(result: Any) -> dict[str, Any]:
    """A final calibration result (result.json) in short, with its microphones for drawing;
    ViewError if it is not one that can be shown."""
    shown = _validated(_ShownResult, result, "result")
    stds = [_norm(m.std_m) for m in shown.microphones]
    mics = [{"id": m.id, "board": m.board, "position_m": list(m.position_m),
             "uncertainty_m": std} for m, std in zip(shown.microphones, stds, strict=True)]
    stds.sort()
    view = {
        "session_id": shown.session_id, "method": shown.method,
        "microphones": mics, "n_microphones": len(mics),
        "median_uncertainty_m": stds[len(stds) // 2] if stds else None,
        "speed_of_sound_m_s": shown.speed_of_sound_m_s,
        "speed_of_sound_std_m_s": shown.speed_of_sound_std_m_s,
        "poses": len(shown.poses), "cameras": [c.name for c in shown.cameras],
        "residual_rms_s": shown.residuals.rms_s if shown.residuals is not None else None,
    }
    _require_finite(view, "result")  # a norm of huge finite numbers overflows
    return view
