"""Live acoustic video: frames per second, latency from sound to pixel, CPU share.

Workload of issue 16: the simulated 72-microphone sphere, a 101 x 101 grid over camera 0's
field of view on the plane 1 m in front of it, the third octave at 4 kHz (1024-sample Hann
blocks, 50 % overlap, a 0.1 s CSM window), the demo scene (a 4 kHz speaker carried around a
loop, a 1.6 kHz one standing, broadband noise), on this machine's cores.

1. The imager alone (in this process, fed as fast as it goes): for delay-and-sum and for
   CLEAN-SC, the time of one video frame (the new samples' spectra, the band CSM, the map,
   its pixels, the drawing over the camera frame), hence the frames per second it can make,
   and its CPU share at a video rate of 25 fps (CPU seconds per frame x 25 / cores).
2. End to end: `micam daemon` in a subprocess on the simulated world in live mode (its
   boards paced at real time, camera 0 streaming at 10 fps), and this process drawing the maps
   of its stream (`LiveFeed`, as `micam live video` does) at 25 fps (delay-and-sum) for --seconds,
   then at 10 fps (CLEAN-SC). Measured: the frames drawn per second, the latency from the scan
   of the newest sample in a map's window to the frame being drawn (p50, p95, max; the
   daemon reads in 21 ms blocks, so that much is in it; add half the CSM window, 50 ms, for
   the age of the window's centre), the CPU share of the daemon and of the viewer, and how far
   the daemon's reads trailed the clock at most (`max_behind_s`: the capture path at real
   time means this stays far below the boards' FIFO, well under a second).

    .venv/bin/python benchmarks/bench_live.py [--seconds 10]

Prints the figures and writes benchmarks/results/live.json.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
from _figures import report
from bench_daemon import cpu_seconds, start_daemon

from acquisition.daemon.client import DaemonClient
from imaging.geometry import ArrayGeometry, geometry_from_dict
from imaging.live import LiveImager, LiveSettings
from imaging.live_frames import MapFrames, caption_of
from micam.live_feed import LiveFeed
from sim.arrays import array_layout
from sim.capture import SimulationOptions
from sim.live_light import render_scene_image
from sim.live_scene import demo_scene, world_truth
from sim.world import World

RESULTS = Path(__file__).with_name("results") / "live.json"
FS = 96_000.0
CORES = len(os.sched_getaffinity(0))


def settings(clean_sc: bool) -> LiveSettings:
    return LiveSettings(band_hz=4000.0, fraction=3, block_size=1024, overlap=0.5,
                        window_s=0.1, depth_m=1.0, grid_shape=(101, 101), clean_sc=clean_sc,
                        image_scale=0.5)


def imager_alone(geometry: ArrayGeometry, world: World, clean_sc: bool, frames: int) -> dict:
    """Seconds and CPU seconds per video frame of the imager fed from the demo scene."""
    scene = demo_scene(world)
    imager = LiveImager(geometry, settings(clean_sc), FS)
    drawn = MapFrames(imager, 25.0, caption_of(imager))
    rng = np.random.default_rng(0)
    camera = world.layout.cameras[0]
    hop = drawn.hop
    start = 0
    warm = int(0.2 * FS)  # a whole window first
    drawn.push(0, scene.mic_volts(0, warm))
    start = warm
    chunks = []
    for _ in range(frames):
        volts = scene.mic_volts(start, hop)
        volts = volts + world.noise.array_noise_v * rng.standard_normal(volts.shape)
        chunks.append((start, volts))
        drawn.add_frame(start, render_scene_image(camera, scene.positions_at(start / FS),
                                                  rng))
        start += hop
    wall, cpu = time.perf_counter(), time.process_time()
    made = components = 0
    for first, volts in chunks:
        for frame in drawn.push(first, volts):
            made += 1
            components += frame.live_map.n_components
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {"frame_ms": round(1e3 * wall / made, 2), "fps": round(made / wall, 1),
            "cpu_share_at_25fps": round(cpu / made * 25.0 / CORES, 3),
            "components_per_frame": round(components / made, 1) if clean_sc else 0}


def end_to_end(client: DaemonClient, geometry: ArrayGeometry, clean_sc: bool, fps: float,
               seconds: float, daemon_pid: int) -> dict:
    """Draw the daemon's live stream for `seconds`; frames, latency and CPU."""
    status = client.status()
    assert status.live is not None
    imager = LiveImager(geometry, settings(clean_sc), status.live.sample_rate_hz)
    with LiveFeed(client, MapFrames(imager, fps, caption_of(imager)), geometry) as feed:
        list(feed.frames_for(0.5))  # the window fills, the subscription settles
        wall, cpu, daemon_cpu = time.perf_counter(), time.process_time(), cpu_seconds(daemon_pid)
        latencies = [f.latency_s for f in feed.frames_for(seconds)]
        wall = time.perf_counter() - wall
        cpu = time.process_time() - cpu
        daemon_cpu = cpu_seconds(daemon_pid) - daemon_cpu
        dropped = feed.dropped
    live = client.status().live
    assert live is not None
    ms = 1e3 * np.array(latencies)
    return {"fps_asked": fps, "fps_drawn": round(len(latencies) / wall, 1),
            "latency_p50_ms": round(float(np.percentile(ms, 50)), 1),
            "latency_p95_ms": round(float(np.percentile(ms, 95)), 1),
            "latency_max_ms": round(float(ms.max()), 1),
            "viewer_cpu_share": round(cpu / wall / CORES, 3),
            "daemon_cpu_share": round(daemon_cpu / wall / CORES, 3),
            "daemon_max_behind_ms": round(1e3 * live.max_behind_s, 1),
            "messages_dropped": dropped}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--frames", type=int, default=50, help="frames of the imager alone")
    args = parser.parse_args()
    world = World(layout=array_layout("sphere72"), seed=0)
    geometry = geometry_from_dict(world_truth(world))
    figures: dict = {"machine": f"{platform.machine()}, {CORES} cores",
                     "workload": "sphere72, 101 x 101 grid at 1 m, 4 kHz third octave, "
                                 "N = 1024, 50 %, 0.1 s window"}
    for name, clean in (("das", False), ("clean_sc", True)):
        for key, value in imager_alone(geometry, world, clean, args.frames).items():
            figures[f"alone_{name}_{key}"] = value
    with tempfile.TemporaryDirectory() as tmp:
        proc, notify = start_daemon(Path(tmp), SimulationOptions(array="sphere72", poses=1,
                                                                 mls_order=10, seed=0))
        try:
            with DaemonClient(f"ipc://{tmp}/c", timeout_s=30.0) as client:
                client.request("live.start", seconds=10.0, camera_fps=10.0, cameras=["cam0"])
                for name, clean, fps in (("das", False, 25.0), ("clean_sc", True, 10.0)):
                    for key, value in end_to_end(client, geometry, clean, fps, args.seconds,
                                                 proc.pid).items():
                        figures[f"live_{name}_{key}"] = value
                client.request("live.stop")
        finally:
            proc.terminate()
            proc.wait(60)
            notify.close()
    report(figures, RESULTS, width=40)


if __name__ == "__main__":
    main()
