"""Maps drawn on camera images put the source on the speaker's pixel, for any camera, and
cover the camera's whole view of the rig plane."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import CalibrationInputError
from imaging import CameraView, CleanScOptions, SteeringModel, beamform_csm, clean_sc
from imaging.evaluate import rig_grid
from imaging.geometry import BoardPose
from imaging.overlay import clean_sources, field_of_view_grid, map_to_image
from sim.geometry import CameraModel

from .helpers import C, point_source_csm, sphere_bench

pytestmark = pytest.mark.slow  # every test here: a simulated scene, beamformed


def view_of(model: CameraModel) -> CameraView:
    return CameraView(model.name, model.width, model.height, model.K, model.dist,
                      model.cam0_to_cam)


@pytest.fixture(scope="module")
def scene():
    world = sphere_bench().world
    speakers = world.speaker_positions()
    pose = BoardPose(0, world.rig_pose, speakers)
    grid = rig_grid(pose, world.rig.speakers_m, 0.002, 0.03)
    mics = world.layout.mic_positions_m
    steering = SteeringModel(grid.points, mics, C)
    maps = [np.maximum(beamform_csm(steering.vectors(8000.0),
                                    point_source_csm(mics, s, 1.0, 8000.0)), 0) for s in speakers]
    return world, grid, speakers, maps


@pytest.mark.parametrize("camera", [0, 2])
def test_map_peak_lands_on_the_speakers_pixel(scene, camera: int) -> None:
    world, grid, speakers, maps = scene
    model = world.layout.cameras[camera]
    view = view_of(model)
    checked = 0
    for speaker, values in zip(speakers, maps, strict=True):
        expected = model.project(speaker[None])[0]  # the simulator's own projection
        if not (0 <= expected[0] < model.width and 0 <= expected[1] < model.height):
            continue  # a side camera sees only part of the rig
        checked += 1
        layer = map_to_image(values, grid, view)
        row, col = np.unravel_index(np.nanargmax(layer), layer.shape)
        assert np.hypot(col - expected[0], row - expected[1]) <= 2.0
    assert checked >= 3


def test_pixels_off_the_grid_are_empty(scene) -> None:
    world, grid, _, maps = scene
    layer = map_to_image(maps[0], grid, view_of(world.layout.cameras[0]))
    assert np.isnan(layer[0, 0]) and np.isfinite(layer).sum() > 1000


@pytest.mark.parametrize("camera", [0, 1])
def test_field_of_view_grid_covers_the_whole_image(scene, camera: int) -> None:
    world, _, speakers, _ = scene
    model = world.layout.cameras[camera]
    pose = BoardPose(0, world.rig_pose, speakers)
    grid = field_of_view_grid(view_of(model), pose, -0.0025, 0.01)
    layer = map_to_image(np.ones(grid.size), grid, view_of(model))
    assert np.isfinite(layer).mean() > 0.995  # every pixel but the last border ones
    np.testing.assert_allclose(grid.spacing(), (0.01, 0.01))
    coarse = field_of_view_grid(view_of(model), pose, -0.0025, 0.001, max_points=10_000)
    assert coarse.size <= 10_000 and coarse.spacing()[0] > 0.001
    with pytest.raises(CalibrationInputError, match="spacing"):
        field_of_view_grid(view_of(model), pose, -0.0025, 0.0)


def test_clean_sources_sum_the_components_of_each_point(scene) -> None:
    world, grid, speakers, _ = scene
    mics = world.layout.mic_positions_m
    steering = SteeringModel(grid.points, mics, C)
    csm = point_source_csm(mics, speakers[[0, 3]], np.array([1.0, 0.5]), 8000.0)
    result = clean_sc(csm, steering.vectors(8000.0), CleanScOptions(), grid_shape=grid.shape)
    points, powers = clean_sources(result, grid)
    assert len(points) == np.count_nonzero(result.clean_map)
    assert powers.sum() == pytest.approx(result.clean_map.sum())
    assert np.all(np.diff(powers) <= 0)  # strongest first
    # The two strongest points are the two sources (sub-grid, within a fraction of a cell).
    assert np.linalg.norm(points[0] - speakers[0]) < 0.5e-3
    assert np.linalg.norm(points[1] - speakers[3]) < 0.5e-3


def test_map_of_the_wrong_size_is_refused(scene) -> None:
    world, grid, _, maps = scene
    with pytest.raises(ValueError, match="grid"):
        map_to_image(maps[0][:-1], grid, view_of(world.layout.cameras[0]))


def test_a_camera_sees_only_what_is_in_front_of_it_and_within_its_image() -> None:
    """What `micam image` warns about: a speaker outside the camera's view."""
    from kernel.rigid import RigidTransform

    view = CameraView(name="cam1", width=640, height=480,
                      K=np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), dist=np.zeros(5),
                      cam0_to_cam=RigidTransform.identity())
    points = np.array([[0.0, 0.0, 1.0],     # straight ahead: the image's centre
                       [0.0, 0.0, -1.0],    # behind the camera (it projects into the image)
                       [1.0, 0.0, 1.0],     # 45 degrees right: x = 820 px, off the image
                       [0.3, 0.2, 1.0]])    # x = 470, y = 340: in it
    assert view.sees(points).tolist() == [True, False, False, True]
