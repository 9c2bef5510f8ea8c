"""Live acoustic video through the audio backend: frames per second, latency, CPU share.

The workload of bench_live.py end to end (a 101 x 101 grid over camera 0's view on the plane
1 m in front of it, the third octave at 4 kHz, 1024-sample Hann blocks, 50 %, a 0.1 s CSM
window, the demo scene), but the sound goes through a real audio stack: a JACK server on its
dummy driver (sim.jack_server: 96 kS/s, 16 inputs, 8 outputs), the simulated world as a JACK
client between the interface's ports (sim.jack_world), and `micam daemon` in a subprocess
recording it through PortAudio (daq.audio, its callbacks, periods and latency) in live mode.
The array is the 15 microphones of one 16-input interface (scatter15), the geometry the
world's truth. This process draws the maps of the daemon's stream as `micam live video` does,
at 25 fps (delay-and-sum) for --seconds, then at 10 fps (CLEAN-SC), and counts the xruns that
ended live mode (each one is restarted: the figures are of the frames drawn).

    .venv/bin/python benchmarks/bench_live_audio.py [--seconds 10] [--period 2048]

Needs jackd and libportaudio2 (apt-get install jackd2 libportaudio2) and JACK-Client. Prints
the figures and writes benchmarks/results/live_audio.json.
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
from bench_live import settings

from acquisition.daemon.client import DaemonClient
from imaging.geometry import ArrayGeometry, geometry_from_dict
from imaging.live import LiveImager
from imaging.live_frames import MapFrames, caption_of
from micam.live_feed import LiveFeed
from sim import jack_server
from sim.capture import SimulationOptions, world_for
from sim.live_scene import world_truth

RESULTS = Path(__file__).with_name("results") / "live_audio.json"
CORES = len(os.sched_getaffinity(0))


def draw(client: DaemonClient, geometry: ArrayGeometry, clean_sc: bool, fps: float,
         seconds: float, daemon_pid: int) -> dict:
    """Draw the daemon's live stream for `seconds` (restarting live mode after an xrun)."""
    latencies: list[float] = []
    restarts = 0
    wall = cpu = daemon_cpu = 0.0
    dropped = 0
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and restarts < 20:
        if client.status().live is None:
            client.request("live.start", seconds=10.0, camera_fps=10.0, cameras=["cam0"])
        imager = LiveImager(geometry, settings(clean_sc), 96_000.0)
        with LiveFeed(client, MapFrames(imager, fps, caption_of(imager)), geometry) as feed:
            list(feed.frames_for(0.5))  # the window fills, the subscription settles
            while (left := deadline - time.monotonic()) > 0:
                w0, c0, d0 = time.perf_counter(), time.process_time(), cpu_seconds(daemon_pid)
                latencies += [f.latency_s for f in feed.frames_for(min(1.0, left))]
                wall += time.perf_counter() - w0
                cpu += time.process_time() - c0
                daemon_cpu += cpu_seconds(daemon_pid) - d0
                if client.status().live is None:  # an xrun ended live mode
                    restarts += 1
                    break
            dropped += feed.dropped
    live = client.status().live
    ms = 1e3 * np.array(latencies or [np.nan])
    return {"fps_asked": fps, "fps_drawn": round(len(latencies) / max(wall, 1e-9), 1),
            "latency_p50_ms": round(float(np.percentile(ms, 50)), 1),
            "latency_p95_ms": round(float(np.percentile(ms, 95)), 1),
            "viewer_cpu_share": round(cpu / max(wall, 1e-9) / CORES, 3),
            "daemon_cpu_share": round(daemon_cpu / max(wall, 1e-9) / CORES, 3),
            "daemon_max_behind_ms": round(1e3 * live.max_behind_s, 1) if live else None,
            "live_restarts_after_xrun": restarts, "messages_dropped": dropped}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--period", type=int, default=jack_server.PERIOD,
                        help="JACK frames per period (the server's buffer)")
    args = parser.parse_args()
    missing = jack_server.missing_audio_stack()
    if missing:
        raise SystemExit(missing)
    options = SimulationOptions(array="scatter15", poses=1, mls_order=10, seed=0,
                                backend="audio")
    world, _ = world_for(options)
    geometry = geometry_from_dict(world_truth(world))
    figures: dict = {"machine": f"{platform.machine()}, {CORES} cores",
                     "workload": "scatter15 through JACK (dummy, 96 kS/s), 101 x 101 grid at "
                                 "1 m, 4 kHz third octave, N = 1024, 50 %, 0.1 s window",
                     "jack_period": args.period}
    with tempfile.TemporaryDirectory() as tmp:
        server = jack_server.JackServer(f"micam-bench-{os.getpid()}", Path(tmp), args.period)
        os.environ.update({k: server.env[k] for k in ("JACK_DEFAULT_SERVER",
                                                      "JACK_NO_AUDIO_RESERVATION")})
        figures["jack_realtime"] = jack_server.realtime_permitted()
        try:
            Path(tmp).chmod(0o700)
            proc, notify = start_daemon(Path(tmp), options)
            try:
                with DaemonClient(f"ipc://{tmp}/c", timeout_s=30.0) as client:
                    for name, clean, fps in (("das", False, 25.0), ("clean_sc", True, 10.0)):
                        for key, value in draw(client, geometry, clean, fps, args.seconds,
                                               proc.pid).items():
                            figures[f"live_{name}_{key}"] = value
                    if client.status().live is not None:
                        client.request("live.stop")
            finally:
                proc.terminate()
                proc.wait(60)
                notify.close()
        finally:
            server.stop()
    report(figures, RESULTS, width=40)


if __name__ == "__main__":
    main()
