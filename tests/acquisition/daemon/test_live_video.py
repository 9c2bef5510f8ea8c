"""Live mode end to end: maps of the daemon's stream that follow the simulated speaker,
a video of live mode and of a recording, and a live recording that Acoular reads and images
as micam does."""

from __future__ import annotations

from collections.abc import Iterator
import io
from contextlib import redirect_stdout
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.contracts.errors import UserError
from acquisition.live.record import ACOULAR_FILE, read_live_recording
from imaging import load_geometry
from imaging.beamform import beamform
from imaging.csm import WelchOptions, band_bins, cross_spectra
from imaging.geometry import ArrayGeometry, geometry_from_dict
from imaging.live import LiveImager, LiveSettings
from imaging.live_frames import MapFrames
from imaging.peaks import subgrid_peak
from imaging.steering import SteeringModel
from imaging.view_plane import depth_plane_grid
from micam.cli import main
from micam.commands.live import _check_grid
from micam.live_feed import LiveFeed, mic_columns

from .helpers import WAIT_S, ThreadDaemon, small_config

pytestmark = pytest.mark.slow  # every test here: a daemon and a live recording, made once

FS = 96_000.0


@pytest.fixture(scope="module")
def live(tmp_path_factory) -> Iterator[ThreadDaemon]:
    """A daemon in live mode on the small simulated world."""
    running = ThreadDaemon(small_config(tmp_path_factory.mktemp("live")))
    with running.client() as client:
        client.request("live.start", seconds=4.0, camera_fps=10.0)
    yield running
    running.stop()


@pytest.fixture(scope="module")
def result_json(small_session: Path, tmp_path_factory) -> Path:
    """A calibration of the daemon's simulated world (the same array and seed: the session
    was captured in it), by `micam calibrate`."""
    path = tmp_path_factory.mktemp("calibrated") / "result.json"
    assert main(["calibrate", str(small_session), "--out", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def geometry(result_json: Path) -> ArrayGeometry:
    return load_geometry(result_json)


@pytest.fixture(scope="module")
def recording(live: ThreadDaemon) -> Path:
    """A second of live mode recorded by `micam live record`, which returns only once the
    recording can be read (read here at once)."""
    with live.client() as client:
        client.wait_until(lambda s: s.live is not None and s.live.held_s >= 1.0, WAIT_S,
                          interval_s=0.05)
    out = io.StringIO()
    with redirect_stdout(out):
        assert main(["live", "record", "--seconds", "1", "--control",
                     live.config.sockets.control]) == 0
    path = Path(out.getvalue().splitlines()[-1].split()[1])
    codes, _, _, frames, _ = read_live_recording(path, "cam0")
    assert codes.shape[0] == round(FS) and frames
    return path


def test_maps_of_the_daemons_stream_follow_the_carried_speaker(live, geometry) -> None:
    """Maps made with the calibration result of the daemon's world: their peaks land within
    4 px of the speaker's true projection (through the true camera) frame after frame."""
    world = live.hardware.world_operator.world
    scene = world.live_scene
    camera = world.layout.cameras[0]
    settings = LiveSettings(band_hz=4000.0, fraction=3, depth_m=1.0, window_s=0.05,
                            image_scale=0.5)
    imager = LiveImager(geometry, settings, FS)
    with live.client() as client, LiveFeed(client, MapFrames(imager, 10.0), geometry) as feed:
        fed = list(feed.frames_for(3.0))
    assert len(fed) >= 5 and feed.dropped == 0
    for f in fed:
        m = f.frame.live_map
        centre_s = (m.end_sample - m.window_samples / 2) / FS
        truth = camera.project(scene.sources[0].trajectory.at(centre_s))[0]
        assert np.linalg.norm(m.peak_px - truth) < 4.0
        assert f.frame.image.shape == (480, 640, 3)
    # drawn over the camera's frames from the first that arrived on (maps may come first)
    samples = [f.frame.camera_sample for f in fed]
    first = next(i for i, sample in enumerate(samples) if sample >= 0)
    assert first < len(samples) // 2 and all(sample >= 0 for sample in samples[first:])


def test_a_video_is_written_from_live_mode_and_from_a_recording(live, result_json, recording,
                                                                tmp_path) -> None:
    control = ["--control", live.config.sockets.control]
    from_live = tmp_path / "live.avi"
    assert main(["live", "video", "--geometry", str(result_json), "--out", str(from_live),
                 "--seconds", "1.0", "--grid", "41", *control]) == 0
    from_recording = tmp_path / "recording.mp4"
    assert main(["live", "video", "--geometry", str(result_json), "--out", str(from_recording),
                 "--recording", str(recording), "--grid", "41", "--window", "0.05"]) == 0
    for path, least in ((from_live, 3), (from_recording, 8)):
        video = cv2.VideoCapture(str(path))
        assert video.isOpened()
        frames = int(video.get(cv2.CAP_PROP_FRAME_COUNT))
        ok, first = video.read()
        video.release()
        assert ok and first.shape == (480, 640, 3) and frames >= least


def test_acoular_reads_a_live_recording_and_makes_micams_map(recording, geometry) -> None:
    """Acoular (TimeSamples on time_data.h5, PowerSpectra, BeamformerBase) and micam (the
    session-format recording, cross_spectra, beamform) give the same third-octave map on the
    live view's plane, and its peak is the live imager's."""
    import acoular as ac

    ac.config.global_caching = "none"
    ac.config.h5library = "h5py"  # the binding micam writes with (PyTables warns at exit)
    codes, fs, _, _, config = read_live_recording(recording, "cam0")
    columns, scale = mic_columns(config.columns, geometry)
    hop = 512
    n = 1024 + hop * ((codes.shape[0] - 1024) // hop)  # whole blocks: Acoular's count is exact
    volts = codes[:n, columns] * scale
    plain = geometry_from_dict({**world_truth_of(geometry), "board_latencies_s": {}})
    grid = depth_plane_grid(plain.camera("cam0"), 1.0, (41, 31))
    bins = band_bins(4000.0, 3, 1024, fs)

    steering = SteeringModel(grid.points, plain.mic_positions_m, plain.speed_of_sound_m_s,
                             "true location")
    ours = beamform(cross_spectra(volts, fs, bins, WelchOptions(1024, 0.5)), steering,
                    precision="double").sum(axis=0)

    source = ac.MaskedTimeSamples(file=str(recording / ACOULAR_FILE), stop=n)
    assert source.sample_freq == fs and source.num_channels == plain.n_mics
    spectra = ac.PowerSpectra(source=source, block_size=1024, window="Hanning", overlap="50%")
    steer = ac.SteeringVector(grid=ac.ImportGrid(pos=grid.points.T),
                              mics=ac.MicGeom(pos_total=plain.mic_positions_m.T),
                              env=ac.Environment(c=plain.speed_of_sound_m_s),
                              steer_type="true location", ref=plain.centre_m)
    theirs = ac.BeamformerBase(freq_data=spectra, steer=steer, r_diag=True).synthetic(4000.0, 3)
    theirs = np.asarray(theirs).ravel()
    # within Acoular's float32 phases (4e-7 of the peak measured)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-5 * ours.max())

    imager = LiveImager(plain, LiveSettings(grid_shape=(41, 31), window_s=n / fs), fs)
    imager.push(volts)
    live_peak = imager.map().peak_index
    # both sub-grid (0.003 of a cell apart here): the live peak against Acoular's grid node
    # were up to 0.7 of a cell apart with identical maps, and 1.1 once under load
    their_peak = subgrid_peak(theirs, grid.shape)
    assert np.hypot(live_peak[0] - their_peak[0], live_peak[1] - their_peak[1]) <= 0.1


def world_truth_of(geometry: ArrayGeometry) -> dict:
    """The geometry as a document again (microphones, c, cameras)."""
    return {"microphones": [{"id": i, "position_m": p.tolist()}
                            for i, p in zip(geometry.mic_ids, geometry.mic_positions_m,
                                            strict=True)],
            "speed_of_sound_m_s": geometry.speed_of_sound_m_s,
            "cameras": [{"name": c.name, "width": c.width, "height": c.height,
                         "K": c.K.tolist(), "dist": c.dist.tolist(),
                         "from_cam0": c.cam0_to_cam.to_json()} for c in geometry.cameras]}


@pytest.mark.parametrize(("option", "value"), [("--grid", "100000"), ("--block", "0")])
def test_a_video_of_an_impossible_size_is_a_usage_error_naming_the_option(
        result_json: Path, recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        option: str, value: str) -> None:
    """--grid 100000 asked for 74.5 GiB and --block 0 divided by zero: both were bugs (exit
    70); now argparse refuses them before anything is read."""
    with pytest.raises(SystemExit) as exited:
        main(["live", "video", "--geometry", str(result_json), "--recording", str(recording),
              "--out", str(tmp_path / "v.avi"), option, value])
    assert exited.value.code == 2
    assert f"error: argument {option}: {value} is not an integer from " in capsys.readouterr().err


def test_a_grid_whose_imager_would_not_fit_is_refused() -> None:
    _check_grid(482, 72)  # about 2 GiB
    with pytest.raises(UserError, match=r"--grid 483: .* at most --grid 482 fits in the 2 GiB"):
        _check_grid(483, 72)
