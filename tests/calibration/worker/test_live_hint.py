"""The live update's hint and coverage: where to hold the rig next, drawn in camera 0's image,
and where the poses taken were (against the simulated truth)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from micam.cli import main
from calibration.pipeline import CalibrationOptions, measure, solve
from calibration.worker.live import live_update


@pytest.fixture(scope="module")
def five_poses(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("live") / "s"
    assert main(["simulate", "--out", str(path), "--array", "scatter48", "--poses", "5",
                 "--mls-order", "9", "--seed", "3", "--quiet"]) == 0
    return path


@pytest.mark.slow
def test_the_hint_lies_in_camera_0s_image_and_the_poses_taken_are_where_they_were(
        five_poses: Path) -> None:
    options = CalibrationOptions(allow_interrupted=True, joint=False)
    m = measure(five_poses, options)
    update = live_update("s", m, solve(m, options))
    assert update.image_size is not None
    width, height = update.image_size
    hint = update.suggestion
    assert hint is not None and len(hint.outline_px) == 4
    assert len(hint.speakers_px) == len(m.data.speakers_rig_m)
    assert all(0 <= u <= width and 0 <= v <= height for u, v in hint.outline_px)
    # The speakers' centroid at the suggested pose projects where its direction points.
    camera = m.cameras.intrinsics[m.cameras.reference_camera]
    d = np.array(hint.direction)
    expected = camera.K @ (d / d[2])
    assert np.allclose(np.mean(hint.speakers_px, axis=0), expected[:2], atol=30.0)
    truth = json.loads((five_poses / "truth.json").read_text())
    true_distance = {f"pose/{p['index']:04d}": float(np.linalg.norm(np.mean(
        p["speakers_m"], axis=0))) for p in truth["poses"]}
    assert [p.step for p in update.poses_taken] == sorted(true_distance)
    for p in update.poses_taken:
        assert p.distance_m == pytest.approx(true_distance[p.step], abs=0.01)
