"""What the page shows, from the daemon's messages: names, flags, camera warnings, results."""

from __future__ import annotations

import json
from datetime import UTC, datetime

import pytest

from acquisition.contracts.protocol import (
    CameraPoses,
    ColumnInfo,
    DescribeResult,
    LevelsEvent,
    QualityInfo,
    RigInfo,
)
from micam.web.view import (
    ViewError,
    camera_warning,
    cameras_view,
    history_point,
    levels_view,
    live_view,
    result_view,
)


def _describe() -> DescribeResult:
    columns = [ColumnInfo(column=0, board="A", channel=0, role="mic", mic_id=7),
               ColumnInfo(column=1, board="A", channel=1, role="mic", mic_id=8),
               ColumnInfo(column=2, board="B", channel=0, role="mic", mic_id=9),
               ColumnInfo(column=3, board="R", channel=0, role="reference")]
    return DescribeResult(
        simulated=True, columns=columns, cameras=["cam0", "cam1"],
        rig=RigInfo(corners_x=6, corners_y=9, square_m=0.03, speakers_m=[(0.0, 0.0, 0.0)]),
        n_poses=20, quality=QualityInfo(clip_fraction=0.999, min_level_dbfs=-60, min_snr_db=10,
                                        min_channel_snr_db=3),
        camera_min_views=4, live_min_poses=4, live=True, preview_fps=2, preview_width=480)


def test_levels_are_named_by_microphone_and_board_with_the_reference_apart() -> None:
    event = LevelsEvent(seq=1, time_utc=datetime.now(UTC), step="pose/0001", file="s0.wav",
                        rms_dbfs=[-20, -0.1, -85, -30], peak_dbfs=[-10, 0, -80, -25],
                        snr_db=[30, 40, 1, 25], clipped_channels=[1], listening=[0, 1, 2],
                        dead_channels=[2], low_snr_channels=[])
    view = levels_view(event, _describe())
    assert view["reference"]["name"] == "reference mic (board R ch 0)"
    assert not view["reference"]["listening"]
    assert [b["board"] for b in view["boards"]] == ["A", "B"]
    assert [c["label"] for c in view["boards"][0]["channels"]] == ["7", "8"]
    assert view["boards"][0]["channels"][1]["flags"] == ["clipped"]
    assert view["flagged"] == {"clipped": ["mic 8 (board A ch 1)"],
                               "dead": ["mic 9 (board B ch 0)"], "low_snr": []}


@pytest.mark.parametrize(("seen", "done", "n", "warned"), [
    (4, 4, 20, None),                  # enough views already
    (0, 0, 20, None),                  # nothing taken yet: no judgement
    (1, 10, 20, "on course"),          # 1 in 10 so far: 3 by the end, short of 4
    (3, 10, 20, None),                 # 3 in 10: 9 by the end
    (1, 18, 20, "cannot be calibrated"),  # even 2 more boards leave it at 3
])
def test_a_camera_on_course_to_stay_uncalibrated_is_warned_about(
        seen: int, done: int, n: int, warned: str | None) -> None:
    warning = camera_warning(seen, n - done, seen, done, 4)
    assert (warning is None) if warned is None else (warning is not None and warned in warning)


def test_the_refmic_image_counts_as_a_board_view() -> None:
    """A 3-pose session with the refmic image still to take gets 4 views: no warning (the
    calibration will use all 4), where counting poses alone said "cannot be calibrated"."""
    before = CameraPoses(camera="cam0", poses_seen=0, board_views=0, views_left=4)
    view = cameras_view(_describe(), [before], 0, 3)
    assert view[0]["warning"] is None
    short = CameraPoses(camera="cam0", poses_seen=0, board_views=0, views_left=3)
    assert "cannot be calibrated: 0 of 4" in cameras_view(_describe(), [short], 0, 3)[0]["warning"]


def test_every_camera_is_listed_with_its_poses() -> None:
    view = cameras_view(_describe(), [CameraPoses(camera="cam0", poses_seen=5)], 6, 20)
    assert [(c["camera"], c["poses_seen"], c["warning"] is None) for c in view] == [
        ("cam0", 5, True), ("cam1", 0, False)]


def _update(**changes: object) -> dict:
    update = {"v": 2, "session_id": "s1", "poses": 6, "mean_uncertainty_m": 4e-4,
              "microphones": [{"id": 1, "position_m": [0, 0, 1], "std_m": [3e-4, 4e-4, 0]}],
              "predicted_accuracy_m": 4e-4, "speed_of_sound_m_s": 343.2}
    return {**update, **changes}


def _result(**changes: object) -> dict:
    result = {"session_id": "s1", "method": "joint",
              "microphones": [{"id": 7, "board": "A", "position_m": [0.1, 0, 1],
                               "std_m": [3e-4, 4e-4, 0]}],
              "speed_of_sound_m_s": 343.2, "speed_of_sound_std_m_s": 0.1,
              "poses": [{}, {}], "cameras": [{"name": "cam0"}], "residuals": {"rms_s": 1e-8}}
    return {**result, **changes}


def test_the_live_view_says_enough_only_at_the_target() -> None:
    update = _update()
    view = live_view(update, target_m=5e-4)
    assert view["enough"] and view["microphones"][0]["uncertainty_m"] == pytest.approx(5e-4)
    assert not live_view(update, target_m=3e-4)["enough"]
    assert not live_view(update, target_m=None)["enough"]
    json.dumps(view, allow_nan=False)


def test_a_result_is_summed_up() -> None:
    view = result_view(_result())
    assert view["n_microphones"] == 1 and view["poses"] == 2 and view["cameras"] == ["cam0"]
    assert view["median_uncertainty_m"] == pytest.approx(5e-4)
    assert view["residual_rms_s"] == 1e-8
    json.dumps(view, allow_nan=False)


BAD_RESULTS: list[tuple[object, str]] = [
    ([], "valid dictionary"),
    ({}, "microphones"),
    (_result(speed_of_sound_m_s=float("nan")), "speed_of_sound_m_s"),
    (_result(speed_of_sound_m_s=float("inf")), "speed_of_sound_m_s"),
    (_result(microphones=[{"id": 1, "position_m": [0, 0], "std_m": [0, 0, 0]}]), "position_m"),
    (_result(microphones=[{"id": "seven", "position_m": [0, 0, 0], "std_m": [0, 0, 0]}]),
     "microphones[0].id"),
    (_result(microphones=[{"id": 1, "position_m": [0, 0, 0], "std_m": [1e300, 1e300, 0]}]),
     "inf"),
    (_result(microphones="many"), "microphones"),
    (_result(cameras=[{"name": 5}]), "cameras[0].name"),
    (_result(residuals=[]), "residuals"),
    (_result(poses=7), "poses"),
]


@pytest.mark.parametrize(("result", "why"), BAD_RESULTS)
def test_a_result_that_cannot_be_shown_says_why(result: object, why: str) -> None:
    with pytest.raises(ViewError, match="this result cannot be shown") as refused:
        result_view(result)
    assert why in str(refused.value)


@pytest.mark.parametrize("update", [
    None, [], _update(poses="six"), _update(speed_of_sound_m_s=float("nan")),
    _update(microphones=[{"id": 1, "position_m": [0, 0, 1], "std_m": [1e300, 1e300, 0]}]),
    _update(suggestion={"distance_m": float("inf")}), _update(extra=1),
])
def test_a_live_calibration_that_cannot_be_shown_says_why(update: object) -> None:
    with pytest.raises(ViewError, match="this live calibration cannot be shown"):
        live_view(update, target_m=5e-4)


def test_a_history_point_is_checked_like_the_rest() -> None:
    point = {"poses": 4, "predicted_accuracy_m": 1e-3, "mean_uncertainty_m": 1e-3,
             "speed_of_sound_m_s": 343.0}
    assert history_point({**point, "other": "ignored"}) == point
    for bad in ({**point, "poses": -1}, {**point, "predicted_accuracy_m": float("nan")},
                {"poses": 4}, "4"):
        with pytest.raises(ViewError, match="live history point cannot be shown"):
            history_point(bad)
