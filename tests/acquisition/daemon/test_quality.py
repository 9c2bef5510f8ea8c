"""Unit tests of the quality checks on synthetic recordings and rendered images."""

from __future__ import annotations

from typing import Literal

import numpy as np
import pytest

from acquisition.contracts.capture_config import column_name
from acquisition.daemon.config import QualityConfig
from acquisition.daemon.quality import (
    checkerboard_corners,
    judge_images,
    judge_recording,
    measure,
)
from sim.capture import SimulationOptions, build_simulated_capture

PRE, BURST = 512, 2047
NAMES = [column_name("mic", 7 - j, "A", j) for j in range(3)]
"""Columns 0, 1, 2 record microphones 7, 6, 5: a message must name the microphone, not the
column (README, "Numbering")."""


def _recording(amplitudes: list[float], noise: float = 30.0, seed: int = 0) -> np.ndarray:
    """Codes: noise everywhere, plus a +-amplitude random burst from PRE on each channel."""
    rng = np.random.default_rng(seed)
    n = PRE + BURST + 500
    x = rng.normal(0.0, noise, (n, len(amplitudes)))
    burst = rng.choice([-1.0, 1.0], size=(BURST, 1))
    x[PRE: PRE + BURST] += burst * np.asarray(amplitudes)
    return np.clip(np.round(x), -32768, 32767).astype(np.int16)


def test_a_burst_late_by_an_interfaces_latency_is_measured_where_it_arrived() -> None:
    """An audio interface's output-to-input latency (here 1024 samples, one JACK period) is
    longer than a short burst: the burst is judged where it arrives, not where it was played."""
    late = np.zeros((PRE + 1024 + BURST + 500, 2), dtype=np.int16)
    on_time = _recording([3000.0, 300.0])
    late[: PRE] = on_time[: PRE]
    late[PRE + 1024:] = on_time[PRE: PRE + late.shape[0] - PRE - 1024]
    levels = measure(late, PRE, BURST, clip_fraction=0.999)
    assert levels.snr_db is not None
    assert levels.rms_dbfs[0] == pytest.approx(20 * np.log10(3000 / 32768), abs=0.3)
    assert levels.snr_db[1] == pytest.approx(20 * np.log10(300 / 30), abs=0.5)


def test_a_burst_cut_off_by_the_end_of_the_recording_fails_with_the_cause() -> None:
    """A latency longer than the recording's silence after the burst: the recording ends in
    the burst, which calibration would read as a shorter, wrong one."""
    cut = _recording([3000.0, 3000.0])[: PRE + BURST // 2]
    failures = judge_recording(measure(cut, PRE, BURST, clip_fraction=0.999), [0, 1], [0, 1],
                               check_dead=False, config=QualityConfig(), names=NAMES)
    assert [f.check for f in failures] == ["level"]
    assert "the recording ends before the burst is over" in failures[0].message
    assert "raise [hardware.capture.burst] post_samples" in failures[0].message


def test_levels_and_snr_match_the_signal() -> None:
    levels = measure(_recording([3000.0, 300.0, 0.0]), PRE, BURST, clip_fraction=0.999)
    assert levels.snr_db is not None
    assert levels.rms_dbfs[0] == pytest.approx(20 * np.log10(3000 / 32768), abs=0.2)
    assert levels.snr_db[0] == pytest.approx(20 * np.log10(3000 / 30), abs=0.5)
    assert levels.snr_db[1] == pytest.approx(20 * np.log10(300 / 30), abs=0.5)
    assert levels.snr_db[2] < 3.0  # no burst: a dead channel
    assert levels.clipped == []


def test_clipping_is_caught_and_its_policy_applied() -> None:
    codes = _recording([40_000.0, 1000.0])
    failures = judge_recording(measure(codes, PRE, BURST, 0.999), listening=[1], mics=[0, 1],
                               check_dead=True, config=QualityConfig(), names=NAMES)
    assert [(f.check, f.policy) for f in failures] == [("clipping", "retry")]
    assert failures[0].message.startswith("clipped on mic 7 (board A ch 0): ")
    quiet = judge_recording(measure(codes, PRE, BURST, 0.999), [1], [0, 1], True,
                            QualityConfig(clipping="ignore"), NAMES)
    assert quiet == []


def test_low_level_low_snr_and_dead_channels() -> None:
    codes = _recording([6.0, 6.0, 0.0], noise=5.0)  # -75 dBFS, SNR 1.6 dB, and a dead one
    failures = judge_recording(measure(codes, PRE, BURST, 0.999), listening=[0, 1],
                               mics=[0, 1, 2], check_dead=True,
                               config=QualityConfig(dead_channels="warn", min_channel_snr_db=0),
                               names=NAMES)
    checks = {f.check: f for f in failures}
    assert set(checks) == {"level", "snr", "dead_channels"}
    assert checks["level"].policy == "retry" and checks["dead_channels"].policy == "warn"
    assert checks["dead_channels"].message.startswith("no burst heard on mic 5 (board A ch 2) ")


def test_good_recording_passes() -> None:
    codes = _recording([2000.0, 1500.0])
    assert judge_recording(measure(codes, PRE, BURST, 0.999), [0, 1], [0, 1], True,
                           QualityConfig(), NAMES) == []


def test_checkerboard_found_in_a_rendered_pose_and_not_in_an_empty_view() -> None:
    sim = build_simulated_capture(SimulationOptions(array="scatter48", poses=1, seed=1))
    camera = sim.cameras[0]
    pattern = (sim.config.rig.corners_x, sim.config.rig.corners_y)
    sim.world.place_rig(sim.poses[0])
    corners = checkerboard_corners(camera.grab().image, pattern)
    assert corners is not None and corners.shape == (pattern[0] * pattern[1], 2)
    blank = np.full((480, 640), 128, np.uint8)
    assert checkerboard_corners(blank, pattern) is None


@pytest.mark.parametrize(
    ("found", "rule", "fails"),
    [({"cam0": True, "cam1": False}, "any", False), ({"cam0": True, "cam1": False}, "all", True),
     ({"cam0": False, "cam1": False}, "any", True), ({}, "all", False)],
)
def test_checkerboard_rule(found: dict[str, bool], rule: Literal["any", "all"],
                           fails: bool) -> None:
    failures = judge_images(found, QualityConfig(checkerboard_in=rule))
    assert bool(failures) is fails
