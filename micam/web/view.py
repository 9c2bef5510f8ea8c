"""What the operator's page shows, made from the daemon's messages.

Pure functions of the protocol's models (acquisition.contracts.protocol): the levels named by
microphone id and board with the reference microphone apart and the flagged channels by name,
each camera's pose count with a warning while it is on course to stay uncalibrated, the live
calibration's microphones with their uncertainty, and the summary of a final result. The
browser only draws what these return.
"""

from __future__ import annotations

import math
from typing import Any

from acquisition.contracts.capture_config import column_name
from acquisition.contracts.protocol import CameraPoses, DescribeResult, LevelsEvent


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


def camera_warning(poses_seen: int, poses_done: int, n_poses: int,
                   min_views: int) -> str | None:
    """Why a camera is on course to stay uncalibrated, or None.

    It cannot be calibrated when even a board in every remaining pose leaves it short of
    `min_views`; it is on course to stay uncalibrated when it keeps finding the board at the
    rate so far (`poses_seen` of `poses_done`) and ends the session short of `min_views`.
    """
    if poses_seen >= min_views:
        return None
    remaining = max(0, n_poses - poses_done)
    if poses_seen + remaining < min_views:
        return (f"cannot be calibrated: {poses_seen} of {min_views} board views needed, and "
                f"only {remaining} poses left")
    if poses_done == 0:
        return None
    projected = poses_seen + remaining * poses_seen / poses_done
    if projected < min_views:
        return (f"on course to stay uncalibrated: the board was seen in {poses_seen} of "
                f"{poses_done} poses; it needs {min_views} views (hold the board in its view)")
    return None


def cameras_view(describe: DescribeResult, seen: list[CameraPoses], poses_done: int,
                 n_poses: int) -> list[dict[str, Any]]:
    """Every camera with its board views so far and its warning (if any)."""
    counts = {c.camera: c.poses_seen for c in seen}
    return [{"camera": name, "poses_seen": counts.get(name, 0),
             "warning": camera_warning(counts.get(name, 0), poses_done, n_poses,
                                       describe.camera_min_views)}
            for name in describe.cameras]


def _norm(v: Any) -> float:
    return math.sqrt(sum(float(x) ** 2 for x in v))


def live_view(update: dict[str, Any], target_m: float | None) -> dict[str, Any]:
    """The live calibration for drawing: microphones with their uncertainty (norm of their
    std, metres), the figures, and whether the predicted accuracy meets `target_m`."""
    mics = [{"id": m["id"], "position_m": m["position_m"], "uncertainty_m": _norm(m["std_m"])}
            for m in update.get("microphones", [])]
    predicted = update.get("predicted_accuracy_m")
    return {**{k: v for k, v in update.items() if k != "microphones"}, "microphones": mics,
            "enough": target_m is not None and predicted is not None and predicted <= target_m}


def result_view(result: dict[str, Any]) -> dict[str, Any]:
    """A final calibration result (result.json) in short, with its microphones for drawing."""
    mics = [{"id": m["id"], "board": m.get("board"), "position_m": m["position_m"],
             "uncertainty_m": _norm(m["std_m"])} for m in result.get("microphones", [])]
    stds = sorted(m["uncertainty_m"] for m in mics)
    residuals = result.get("residuals") or {}
    return {
        "session_id": result.get("session_id"), "method": result.get("method"),
        "microphones": mics, "n_microphones": len(mics),
        "median_uncertainty_m": stds[len(stds) // 2] if stds else None,
        "speed_of_sound_m_s": result.get("speed_of_sound_m_s"),
        "speed_of_sound_std_m_s": result.get("speed_of_sound_std_m_s"),
        "poses": len(result.get("poses", [])), "cameras": [c.get("name") for c in
                                                           result.get("cameras", [])],
        "residual_rms_s": residuals.get("rms_s") if isinstance(residuals, dict) else None,
    }
