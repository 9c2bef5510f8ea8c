"""Maps drawn on camera images put the source on the speaker's pixel, for any camera."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from calibration.imaging import CameraView, SteeringModel, beamform_csm
from calibration.imaging.evaluate import rig_grid
from calibration.imaging.geometry import BoardPose
from calibration.imaging.overlay import map_to_image, render_overlay, spread_components, write_png
from sim.geometry import CameraModel

from .helpers import C, point_source_csm, sphere_bench


def view_of(model: CameraModel) -> CameraView:
    return CameraView(model.name, model.width, model.height, model.K, model.dist,
                      model.from_cam0.R, model.from_cam0.t)


@pytest.fixture(scope="module")
def scene():
    world = sphere_bench().world
    speakers = world.speaker_positions()
    pose = BoardPose(0, world.rig_pose.R, world.rig_pose.t, speakers)
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


def test_overlay_png_keeps_the_image_outside_the_layer(scene, tmp_path: Path) -> None:
    world, grid, _, maps = scene
    model = world.layout.cameras[0]
    image = np.full((model.height, model.width), 90, np.uint8)
    layer = map_to_image(spread_components(maps[1], grid), grid, view_of(model))
    out = render_overlay(image, layer, dynamic_range_db=10.0)
    write_png(tmp_path / "map.png", out)
    back = cv2.imread(str(tmp_path / "map.png"))
    assert back.shape == (model.height, model.width, 3)
    assert np.all(back[0, 0] == 90) and not np.all(back == 90)
    assert not list(tmp_path.glob("*.partial"))
    with pytest.raises(ValueError, match="dynamic range"):
        render_overlay(image, layer, dynamic_range_db=0.0)
    with pytest.raises(ValueError, match="grid"):
        map_to_image(maps[0][:-1], grid, view_of(model))
