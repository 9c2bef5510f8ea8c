"""The rig and array description: what it accepts, how a capture configuration becomes one,
and that every refusal names the field, what is wrong and what to write instead."""

from __future__ import annotations

import copy
import re
from typing import Any

import pytest

from acquisition.contracts.config_model import models_within
from acquisition.contracts.rig_description import (
    DescriptionError,
    RigArrayDescription,
    validate_description,
)
from kernel.air import speed_of_sound
from sim.capture import SimulationOptions, build_simulated_capture


def _valid() -> dict[str, Any]:
    return {
        "sample_rate_hz": 48000,
        "rig": {"corners_x": 6, "corners_y": 9, "square_m": 0.03,
                "speakers_m": [[-0.06, 0.0, -0.0025], [0.21, 0.0, -0.0025],
                               [-0.06, 0.24, -0.0025]]},
        "channels": [{"group": "a", "columns": [0, 1, 2], "mic_ids": [0, 1, 2]},
                     {"group": "b", "columns": [3, 4], "mic_ids": [3, 4]}],
        "reference": {"group": "a", "reference_recordings_column": 0},
        "burst": {"mls_order": 12},
        "cameras": [{"name": "cam0", "width": 1280, "height": 960}],
    }


def _with(path: str, value: Any) -> dict[str, Any]:
    """The valid description with `path` (dotted, [i] for list items) set (None: removed)."""
    doc = copy.deepcopy(_valid())
    keys = [int(k) if k.isdigit() else k for k in re.split(r"\.|\[|\]\.?", path) if k]
    target: Any = doc
    for key in keys[:-1]:
        target = target[key]
    if value is None:
        del target[keys[-1]]
    else:
        target[keys[-1]] = value
    return doc


def test_a_valid_description_reads_as_calibration_needs_it() -> None:
    d = validate_description(_valid())
    assert d.microphones() == [(0, 0, "a"), (1, 1, "a"), (2, 2, "a"), (3, 3, "b"), (4, 4, "b")]
    assert d.reference_distances_m() == (0.002,) * 3
    assert not d.reference_on_poses
    assert d.burst.n_samples == 4095
    assert d.rig.origin_square == "dark" and d.rig.print_scale_std == 2e-3


REFUSALS = [
    ("rig.square_m", -0.03, "rig.square_m"),
    ("rig.square_m", None, "rig.square_m: Field required"),
    ("rig.origin_square", "black", "rig.origin_square"),
    ("rig.colour", "dark", "unknown key 'colour'"),
    ("rig.corners_x", 7, "rig.corners_x, rig.corners_y: a 7 x 9 pattern"),
    ("rig.corners_x", 9, "a square grid"),
    ("rig.corners_x", 2, "rig.corners_x: Input should be greater than or equal to 3"),
    ("rig", {**_valid()["rig"], "corners_y": 8, "marker_square": [2, 3]},
     "rig.marker_square: square [2, 3] is the board's centre"),
    ("rig.marker_square", [5, 0], "rig.marker_square: square [5, 0] is not between"),
    ("channels[1].columns", [2, 4], "channels[1].columns: column 2 is already in channels[0]"),
    ("channels[1].mic_ids", [3], "channels[1].mic_ids: 1 ids for 2 columns"),
    ("channels[1].mic_ids", [2, 5], "channels[1].mic_ids: microphone 2 is already"),
    ("channels[1].group", "a", "channels[1].group: 'a' is named twice"),
    ("channels[1].group", "board/1", "channels[1].group"),
    ("reference.pose_recordings_column", 4, "reference.pose_recordings_column: column 4"),
    ("reference.distance_from_speaker_m", [0.002, 0.002], "2 distances for 3 speakers"),
    ("reference.distance_from_speaker_m", 2.0, "2.0 m is not within"),
    ("burst.mls_order", 30, "burst.mls_order"),
    ("burst", {"mls_order": 10, "periods": 2}, "burst: 2 periods of an MLS of order 10"),
    ("sample_rate_hz", None, "sample_rate_hz: Field required"),
    ("cameras[0].name", "../cam0", "cameras[0].name"),
    ("cameras", [{"name": "c", "width": 10, "height": 10}] * 2, "'c' is named twice"),
    ("cameras[0].intrinsics", {"camera_matrix": [[900, 0, 640], [0, 900, 480], [0, 0, 1]]},
     "cameras[0].intrinsics.std: a prior needs"),
    ("cameras[0].intrinsics", {"use": "fixed",
                               "camera_matrix": [[900, 0, 640], [0, 900, 480], [0, 1, 1]]},
     "cameras[0].intrinsics.camera_matrix"),
    ("air", {"temperature_c": 21.0}, "air.temperature_std_c: missing"),
    ("air", {"temperature_c": 21.0, "temperature_std_c": 0.1, "speed_of_sound_m_s": 343.0,
             "speed_of_sound_std_m_s": 0.1}, "air: both"),
    ("air", {}, "air: nothing measured"),
]


@pytest.mark.parametrize(("path", "value", "words"), REFUSALS)
def test_every_refusal_names_the_field_the_problem_and_what_to_write(
        path: str, value: Any, words: str) -> None:
    with pytest.raises(DescriptionError) as caught:
        validate_description(_with(path, value), "lab.toml")
    message = str(caught.value)
    assert message.startswith("lab.toml is invalid:")
    problems = message.splitlines()[1:]
    assert any(words in line for line in problems), message
    for line in problems:
        assert re.match(r"\s+[a-z_]+(\[\d+\])?[.:\[, ]", line), line  # starts with a field
        assert "write" in line or "it accepts" in line, line  # and says what to write


def test_pydantic_refusals_carry_the_field_example() -> None:
    with pytest.raises(DescriptionError) as caught:
        validate_description(_with("rig.square_m", -0.03))
    assert "write e.g. square_m = 0.03 (side of one printed square, metres)" in str(caught.value)


def test_every_model_refuses_unknown_keys() -> None:
    for model in models_within(RigArrayDescription):
        assert model.model_config.get("extra") == "forbid", model


def test_known_air_gives_c_and_its_std() -> None:
    d = validate_description(_with("air", {"temperature_c": 24.0, "temperature_std_c": 0.5,
                                           "relative_humidity": 0.4,
                                           "relative_humidity_std": 0.0}))
    c, std = d.air.speed_of_sound_prior()  # type: ignore[union-attr]
    assert c == pytest.approx(speed_of_sound(24.0, 0.4), abs=1e-12)
    # the derivative, against a central difference of Cramer's formula (the pressure's
    # 2 kPa of uncertainty adds a little)
    slope = (speed_of_sound(24.01, 0.4) - speed_of_sound(23.99, 0.4)) / 0.02
    assert std == pytest.approx(0.5 * slope, rel=1e-3)
    # without a hygrometer, the humidity's range dominates
    d = validate_description(_with("air", {"temperature_c": 24.0, "temperature_std_c": 0.5}))
    assert d.air.speed_of_sound_prior().std_m_s > 0.6  # type: ignore[union-attr]
    d = validate_description(_with("air", {"speed_of_sound_m_s": 344.1,
                                           "speed_of_sound_std_m_s": 0.05}))
    known = d.air.speed_of_sound_prior()  # type: ignore[union-attr]
    assert (known.c_m_s, known.std_m_s) == (344.1, 0.05)



def test_a_capture_configuration_derives_its_description() -> None:
    config = build_simulated_capture(SimulationOptions(array="scatter48", poses=2,
                                                       mls_order=9, seed=3)).config
    d = config.description({"cam0": (1280, 960)})
    columns = config.columns
    ref = [c.role for c in columns].index("reference")
    assert d.reference.pose_recordings_column == ref == d.reference.reference_recordings_column
    assert d.reference.group == config.reference.board
    assert [m for m, _, _ in d.microphones()] == [c.mic_id for c in columns if c.role == "mic"]
    assert {g for _, _, g in d.microphones()} == {c.board for c in columns if c.role == "mic"}
    assert d.burst.n_samples == config.burst.n_samples
    assert d.rig == config.rig
    assert d.cameras[0].width == 1280
    with pytest.raises(DescriptionError, match="no image of camera cam0"):
        config.description({})


def test_a_capture_configuration_states_its_board_colours() -> None:
    config = build_simulated_capture(SimulationOptions(array="scatter48", poses=2,
                                                       mls_order=9, seed=3)).config
    doc = config.model_dump(mode="json")
    doc["rig"]["origin_square"] = "light"
    assert type(config).model_validate(doc).rig.origin_square == "light"
    doc["speakers"][1]["rig_position_m"] = [0.0, 0.0, 0.0]
    with pytest.raises(ValueError, match=r"speakers\[1\].rig_position_m.*write the same"):
        type(config).model_validate(doc)


def test_a_capture_configuration_refuses_periods_too_short_for_the_room() -> None:
    """Two periods of 5 ms fold every path beyond 2.7 m onto the circle's other side: the
    daemon's configuration says so before anything is recorded."""
    config = build_simulated_capture(SimulationOptions(array="scatter48", poses=2,
                                                       mls_order=9, seed=3)).config
    doc = config.model_dump(mode="json")
    assert doc["burst"]["periods"] == 1  # a short test sequence: one period by default
    doc["burst"]["periods"] = 2
    with pytest.raises(ValueError, match="burst: 2 periods of an MLS of order 9 .* write "
                                         "mls_order = 12 or more"):
        type(config).model_validate(doc)
    doc["burst"]["mls_order"] = 12
    assert type(config).model_validate(doc).description(
        {"cam0": (1280, 960)}).burst.steady_window == (512 + 4095, 512 + 2 * 4095)
