"""The live imaging pipeline: the sliding CSM against the batch one, the scan plane and its
pixel table, and a moving simulated source followed by the map's peak frame after frame."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calibration.errors import CalibrationInputError
from imaging.csm import WelchOptions, band_bins, cross_spectra
from imaging.csm_calibration import ChannelResponses, correct_csm
from imaging.geometry import geometry_from_dict
from imaging.live import LiveImager, LiveSettings
from imaging.live_draw import draw_live_frame
from imaging.live_frames import MapFrames
from imaging.overlay import ImageMapper, map_to_image
from imaging.sliding_csm import SlidingCsm
from imaging.view_plane import depth_plane_grid
from sim.arrays import array_layout
from sim.live_scene import LiveScene, LiveSource, Trajectory, world_truth
from sim.world import World

FS = 96_000.0


@pytest.fixture(scope="module")
def world() -> World:
    return World(layout=array_layout("sphere72"), seed=3)


def test_sliding_csm_equals_the_batch_csm_of_its_window() -> None:
    rng = np.random.default_rng(0)
    x = rng.standard_normal((20_000, 5))
    options = WelchOptions(1024, 0.5)
    bins = band_bins(4000.0, 3, 1024, FS)
    responses = ChannelResponses(np.array([1000.0, 8000.0]),
                                 np.exp(1j * rng.uniform(-0.2, 0.2, (2, 5))), "test")
    sliding = SlidingCsm(5, FS, bins, options, n_blocks=7, responses=responses)
    for chunk in np.array_split(x, [333, 1000, 1001, 7000, 12_345]):  # any chunking
        sliding.push(chunk)
    end = sliding.last_block_end
    window = x[end - sliding.window_samples: end]
    batch = correct_csm(cross_spectra(window, FS, bins, options), responses)
    assert batch.n_blocks == 7
    np.testing.assert_allclose(sliding.csm(), batch.csm, rtol=1e-10, atol=1e-14)


def test_sliding_csm_refuses_a_chunk_of_the_wrong_width() -> None:
    sliding = SlidingCsm(4, FS, np.array([40]), WelchOptions(1024), 2)
    with pytest.raises(ValueError, match="chunks must be"):
        sliding.push(np.zeros((10, 3)))


def test_the_depth_plane_fills_the_image_and_a_smaller_image_samples_the_same_map(world
                                                                                 ) -> None:
    geometry = geometry_from_dict(world_truth(world))
    camera = geometry.camera("cam0")
    grid = depth_plane_grid(camera, 1.5, (31, 21))
    assert np.allclose(grid.points[:, 2], 1.5)
    corners = camera.project(grid.points[[0, 20, 630, 650]])
    assert corners[:, 0].min() < 5 and corners[:, 0].max() > camera.width - 6
    u, v = np.meshgrid(np.arange(31.0), np.arange(21.0), indexing="ij")
    values = (0.3 * u + 0.7 * v).ravel()  # linear on the grid: bilinear sampling is exact
    full = map_to_image(values, grid, camera)
    half = ImageMapper(grid, camera, 0.5).to_image(values)
    assert half.shape == (480, 640)
    # a pixel of the half-size image is centred between four of the full one
    np.testing.assert_allclose(half[100:380:7, 100:540:7],
                               0.25 * (full[200:760:14, 200:1080:14] + full[201:761:14, 200:1080:14]
                                       + full[200:760:14, 201:1081:14]
                                       + full[201:761:14, 201:1081:14]), atol=2e-3)
    with pytest.raises(CalibrationInputError, match="depth"):
        depth_plane_grid(camera, -1.0)


@pytest.mark.parametrize("clean_sc", [False, True])
@pytest.mark.slow
def test_the_map_peak_follows_a_carried_speaker_frame_after_frame(world, clean_sc) -> None:
    """A speaker carried across the view at 1 m (0.4 m/s) with a second tone elsewhere in
    another band and broadband noise: at every video frame the peak of the map in the first
    tone's third octave lies within 3 pixels of the speaker's true projection at the centre of
    the CSM's window."""
    geometry = geometry_from_dict(world_truth(world))
    camera = geometry.camera("cam0")
    path = Trajectory(np.array([[-0.35, -0.15, 1.0], [0.25, 0.05, 1.0], [0.1, 0.25, 1.0]]),
                      np.array([0.0, 1.5, 2.0]))
    scene = LiveScene(world, [LiveSource(path, 0.05, 4000.0),
                              LiveSource(Trajectory.still([0.3, -0.2, 1.0]), 0.05, 1000.0),
                              LiveSource(Trajectory.still([-0.4, 0.3, 2.0]), 0.01, None)])
    settings = LiveSettings(band_hz=4000.0, fraction=3, window_s=0.05, depth_m=1.0,
                            clean_sc=clean_sc)
    imager = LiveImager(geometry, settings, FS)
    rng = np.random.default_rng(2)
    hop = int(FS / 25)  # 25 frames per second
    errors = []
    for start in range(0, int(2.0 * FS), hop):
        chunk = scene.mic_volts(start, hop)
        imager.push(chunk + world.noise.array_noise_v * rng.standard_normal(chunk.shape))
        if not imager.ready:
            continue
        frame = imager.map()
        centre_s = (frame.end_sample - frame.window_samples / 2) / FS
        truth_px = camera.project(path.at(centre_s))[0]
        errors.append(float(np.linalg.norm(frame.peak_px - truth_px)))
    assert len(errors) >= 45
    assert max(errors) < 3.0, errors


def test_a_frame_is_drawn_over_the_camera_image_at_the_map_peak(world) -> None:
    geometry = geometry_from_dict(world_truth(world))
    source = LiveSource(Trajectory.still([0.1, 0.1, 1.0]), 0.05, 4000.0)
    imager = LiveImager(geometry, LiveSettings(image_scale=0.5), FS)
    imager.push(LiveScene(world, [source]).mic_volts(0, 12_000))
    frame = imager.map()
    level = imager.level_image(frame)
    grey = np.full((960, 1280), 100, dtype=np.uint8)
    drawn = draw_live_frame(grey, level, 15.0, frame.peak_px, "4 kHz", 0.5)
    assert drawn.shape == (480, 640, 3)
    u, v = np.round(frame.peak_px * 0.5).astype(int)
    far = drawn[20, 620].astype(int)  # a corner far below the peak's level: the camera image
    assert np.all(far == 100)
    assert abs(int(drawn[v + 8, u].astype(int).sum()) - 300) > 60  # coloured near the peak


def test_settings_refuse_a_band_that_is_neither_octave_nor_third() -> None:
    with pytest.raises(CalibrationInputError, match="octave"):
        LiveSettings(fraction=12)


def test_the_simulated_camera_draws_the_source_where_it_projects(world) -> None:
    from sim.live_light import render_scene_image

    model = world.layout.cameras[0]
    where = np.array([[0.2, -0.1, 1.2]])
    image = render_scene_image(model, where, np.random.default_rng(0), noise_grey=0.0)
    dark = np.argwhere(image < 60)
    centre = dark.mean(axis=0)[::-1]  # (u, v)
    assert np.linalg.norm(centre - model.project(where)[0]) < 0.5


def test_the_calibrated_microphone_responses_are_corrected(world) -> None:
    """Channels delayed in proportion to their x (a phase error that moves the peak by 39 px
    at 1 m): with the delays stated as the calibration's microphone_responses the peak
    is back on the speaker."""
    doc = world_truth(world)
    mics = world.layout.mic_positions_m
    delays = 1e-4 * mics[:, 0]  # seconds: +-15 us across the sphere
    where = np.array([0.05, 0.0, 1.0])
    source = LiveSource(Trajectory.still(where.tolist()), 0.05, 4000.0)
    volts = LiveScene(world, [source]).mic_volts(0, 12_000)
    spectra = np.fft.rfft(volts, axis=0)
    freqs = np.fft.rfftfreq(volts.shape[0], 1 / FS)
    delayed = np.fft.irfft(spectra * np.exp(-2j * np.pi * np.outer(freqs, delays)),
                           n=volts.shape[0], axis=0)
    band = np.array([3000.0, 5000.0])
    responses = {"frequencies_hz": band.tolist(), "microphones": [
        {"id": m, "gain": [1.0, 1.0], "phase_rad": (-2 * np.pi * band * tau).tolist()}
        for m, tau in enumerate(delays)]}
    truth_px = world.layout.cameras[0].project(where)[0]
    errors = []
    for document in (doc, {**doc, "microphone_responses": responses}):
        imager = LiveImager(geometry_from_dict(document), LiveSettings(), FS)
        imager.push(delayed)
        errors.append(float(np.linalg.norm(imager.map().peak_px - truth_px)))
    assert errors[0] > 10.0 and errors[1] < 0.5, errors


def test_a_running_view_is_retuned_without_a_gap(world) -> None:
    """A range changed while running is drawn at the next frame, from the same window (the
    imager shares its CSM); another band starts a new window at the stream's next sample."""
    geometry = geometry_from_dict(world_truth(world))
    scene = LiveScene(world, [LiveSource(Trajectory.still([0.1, 0.1, 1.0]), 0.05, 4000.0)])
    settings = LiveSettings(window_s=0.05, grid_shape=(31, 31), image_scale=0.25)  # 2.4 hops
    frames = MapFrames(LiveImager(geometry, settings, FS), 50.0)
    hop = frames.hop
    drawn = [f for start in range(0, 4 * hop, hop)
             for f in frames.push(start, scene.mic_volts(start, hop))]
    before, narrow = drawn[-1], frames.imager
    wider = narrow.with_range(40.0)
    assert wider.csm is narrow.csm and wider.settings.dynamic_range_db == 40.0
    frames.retune(wider, "40 dB")
    after = frames.push(4 * hop, scene.mic_volts(4 * hop, hop))
    assert len(after) == 1 and after[0].settings.dynamic_range_db == 40.0
    shown = [np.isfinite(narrow.level_image(before.live_map)).mean(),
             np.isfinite(wider.level_image(after[0].live_map)).mean()]
    assert shown[1] > 1.5 * shown[0], shown  # 40 dB of the map reach further than 15
    frames.retune(LiveImager(geometry, replace(settings, band_hz=2000.0), FS), "2 kHz")
    window = frames.imager.csm.window_samples
    later = [f for start in range(5 * hop, 5 * hop + window, hop)
             for f in frames.push(start, scene.mic_volts(start, hop))]
    assert later and later[0].live_map.end_sample >= 5 * hop + window - hop
    assert all(f.settings.band_hz == 2000.0 for f in later)
