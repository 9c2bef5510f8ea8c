"""Arrays, wiring and poses of the simulated world."""

from __future__ import annotations

import numpy as np
import pytest

from daq import board_model
from sim.arrays import ARRAY_KINDS, array_layout, sphere72
from sim.errors import SimulationInputError
from sim.geometry import Rig
from sim.poses import PoseSamplingError, in_view, rig_points, sample_poses
from sim.simulated_operator import SimulatedOperator, reference_stand_position
from sim.world import World


def test_sphere_is_wired_as_in_the_paper() -> None:
    layout = sphere72()
    models = [b.model for b in layout.boards]
    assert models[:9] == ["DT9836-12-2"] * 3 + ["DT9816-A"] * 6
    assert layout.n_mics == 72 and len(layout.cameras) == 3
    assert layout.body is not None
    radii = np.linalg.norm(layout.mic_positions_m - layout.body.centre_m, axis=1)
    assert np.allclose(radii, 0.15)
    used = {(r.board, r.channel) for r in layout.mic_inputs}
    assert len(used) == 72
    for out in layout.speaker_outputs:
        assert board_model(layout.boards[out.board].model).n_outputs > out.channel
    assert layout.reference_input not in layout.mic_inputs


@pytest.mark.parametrize("kind", ARRAY_KINDS)
def test_every_layout_has_distinct_channels(kind: str) -> None:
    layout = array_layout(kind)
    refs = [*layout.mic_inputs, layout.reference_input]
    assert len(set(refs)) == len(refs)
    for r in refs:
        assert r.channel < board_model(layout.boards[r.board].model).n_inputs


def test_unknown_array_is_refused() -> None:
    with pytest.raises(SimulationInputError, match="sphere72"):
        array_layout("cube")


@pytest.mark.parametrize("distance", [(0.6, 1.0), (0.5, 3.0), (0.4, 0.6)])
def test_poses_are_in_view_and_in_range(distance: tuple[float, float]) -> None:
    layout, rig = sphere72(), Rig()
    poses = sample_poses(layout.cameras[0], rig, 15, distance, np.random.default_rng(2))
    for pose in poses:
        d = np.linalg.norm(pose.apply(rig.centre()))
        assert distance[0] - 1e-9 <= d <= distance[1] + 1e-9
        assert in_view(layout.cameras[0], pose.apply(rig_points(rig)), 0.0)
        # the printed face looks at the camera
        assert pose.R[:, 2] @ (-pose.apply(rig.centre())) > 0


def test_impossible_distance_range_is_explained() -> None:
    layout, rig = sphere72(), Rig()
    with pytest.raises(PoseSamplingError, match="widen the distance range"):
        sample_poses(layout.cameras[0], rig, 1, (0.1, 0.12), np.random.default_rng(0))


def test_reference_stand_is_out_of_view_but_the_rig_on_it_is_seen() -> None:
    layout = sphere72()
    world = World(layout=layout)
    cam = layout.cameras[0]
    stand = reference_stand_position(cam)
    assert not in_view(cam, stand[None, :], 0.0)
    op = SimulatedOperator(world, [], stand)
    pose = op.rig_pose_on_stand()
    assert np.allclose(pose.apply(world.rig.reference_mark_m), stand)
    assert in_view(cam, pose.apply(world.rig.corner_points()), 10.0)


def test_hidden_parameters_depend_on_the_seed_only() -> None:
    a, b, c = (World(layout=sphere72(), seed=s) for s in (1, 1, 2))
    assert np.array_equal(a.mic_gains, b.mic_gains)
    assert not np.array_equal(a.mic_gains, c.mic_gains)
    assert np.all((a.board_latencies_s >= 1e-6) & (a.board_latencies_s <= 5e-6))
