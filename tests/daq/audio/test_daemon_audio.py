"""`micam daemon` on the audio backend, on a real JACK server with the world as a JACK client:
a 6-pose calibration session captured and calibrated (the accuracy the same world gives
through the simulated boards), then live acoustic video made with that calibration.

The daemon runs in a process of its own, as it does on a lab PC: its audio callbacks then
share their interpreter with the daemon's work only, not with this test's imaging."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from imaging import load_geometry
from imaging.live import LiveImager, LiveSettings
from imaging.live_frames import MapFrames
from micam.cli import main
from micam.live_feed import LiveFeed
from sim.capture import SimulationOptions, world_for
from sim.live_scene import demo_scene

from ...acquisition.daemon.helpers import DaemonProcess, capture_all

pytestmark = pytest.mark.slow  # every test here: a JACK server and the world as its client

WORLD: dict[str, Any] = {"array": "scatter15", "poses": 6, "mls_order": 10, "seed": 3, "backend": "audio"}
"""15 microphones and the reference on the 16 inputs, 6 poses, bursts of 1023 samples."""
SIMULATED_BOARDS_MM = 0.041
"""`micam simulate --array scatter15 --poses 6 --mls-order 10 --seed 3` (the same world on
the simulated boards), then `micam calibrate`: the mean microphone error (docs/hardware.md)."""


def audio_daemon(root: Path, world: dict, env: dict[str, str] | None = None) -> DaemonProcess:
    """`micam daemon` on the simulated world through the audio backend, sockets under root."""
    root.chmod(0o700)
    simulation = "\n".join(f"{k} = {json.dumps(v)}" for k, v in world.items())
    config = root / "daemon.toml"
    config.write_text(f'session_root = "{root}/sessions"\npoll_interval_s = 0.02\n'
                      f'[sockets]\ncontrol = "ipc://{root}/control"\n'
                      f'events = "ipc://{root}/events"\n[simulation]\n{simulation}\n')
    daemon = DaemonProcess(config, root, env=env or {})
    daemon.wait_message("READY=1")
    return daemon


@pytest.fixture(scope="module")
def daemon(jack_server, tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:  # noqa: ANN001
    running = audio_daemon(tmp_path_factory.mktemp("audio-daemon"), WORLD)
    yield running
    running.proc.terminate()
    running.wait_exit()


@pytest.fixture(scope="module")
def session(daemon: DaemonProcess) -> Path:
    with daemon.client(timeout_s=30.0) as client:
        client.request("session.start")
        status = capture_all(client, limit=120)  # an xrun of this loaded machine: again
    assert status.session is None
    (path,) = (daemon.root / "sessions").iterdir()
    return path


@pytest.fixture(scope="module")
def result(session: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("audio-result") / "result.json"
    assert main(["calibrate", str(session), "--out", str(path)]) == 0
    return path


def test_a_six_pose_session_through_the_audio_stack_calibrates(session: Path,
                                                                result: Path) -> None:
    truth = json.loads((session / "truth.json").read_text())
    found = json.loads(result.read_text())
    true_m = {m["id"]: np.array(m["position_m"]) for m in truth["microphones"]}
    errors = [np.linalg.norm(np.array(m["position_m"]) - true_m[m["id"]])
              for m in found["microphones"]]
    assert len(errors) == 15
    assert 1e3 * float(np.mean(errors)) < 3 * SIMULATED_BOARDS_MM  # 0.05 mm measured here
    manifest = json.loads((session / "manifest.json").read_text())
    assert manifest["capture"]["boards"][0]["model"] == "audio"


def test_live_video_through_the_audio_stack_follows_the_carried_speaker(
        daemon: DaemonProcess, result: Path) -> None:
    """Maps of the daemon's live stream, made with the calibration of the session captured
    through the same stack, peak where the 4 kHz speaker carried around its loop is, in
    frame after frame (within 25 px: the world client's scene starts a few tens of ms before
    the stream's sample 0, and the speaker moves)."""
    geometry = load_geometry(result)
    world, _ = world_for(SimulationOptions(**WORLD))
    camera = world.layout.cameras[0]
    source = demo_scene(world).sources[0]
    settings = LiveSettings(band_hz=4000.0, fraction=3, depth_m=1.0, window_s=0.05,
                            image_scale=0.5)
    with daemon.client() as client:
        for _ in range(3):  # an xrun ends live mode (a LiveFault): start it again
            client.request("live.start", seconds=4.0, camera_fps=10.0)
            imager = LiveImager(geometry, settings, 96_000.0)
            with LiveFeed(client, MapFrames(imager, 10.0), geometry) as feed:
                fed = list(feed.frames_for(2.0))
            if client.status().live is None:
                continue
            client.request("live.stop")
            break
    assert len(fed) >= 5 and feed.dropped == 0
    misses = []
    for f in fed:
        m = f.frame.live_map
        centre_s = (m.end_sample - m.window_samples / 2) / 96_000.0
        truth = camera.project(source.trajectory.at(centre_s))[0]
        misses.append(float(np.linalg.norm(m.peak_px - truth)))
    assert max(misses) < 25.0, misses
