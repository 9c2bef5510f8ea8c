"""`micam live start|stop|record|video`: the daemon's live mode, and acoustic video from it or
from a live recording (docs/live.md)."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from acquisition.contracts.errors import UserError

from ..outputs import check_outputs
from .client_options import add_client_arguments
from .bounded import BAND_HZ, DEPTH_M, RANGE_DB, integer, number, positive
from .imaging_options import geometry_file

MAX_GRID = 1000
"""The most scan points across each side of the view (a million in all)."""
MAX_GRID_BYTES = 2 * 2**30
"""The ceiling of the imager's memory for the grid: its steering vectors, powers and their
temporaries take about BYTES_PER_POINT_AND_MIC (measured: 122 at 201 x 201 points and 72
microphones, 73 at 401 x 401), so 72 microphones allow a grid of up to 482."""
BYTES_PER_POINT_AND_MIC = 128


def _add_imaging_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--geometry", required=True, type=Path, metavar="FILE",
                   help="calibration result.json (or a simulated session's truth.json)")
    p.add_argument("--out", required=True, type=Path,
                   help="video file to write: .mp4 (MPEG-4) or .avi (MJPEG)")
    p.add_argument("--band", type=BAND_HZ, default=4000.0, metavar="HZ",
                   help="band centre frequency (default 4000)")
    p.add_argument("--fraction", type=int, choices=(1, 3), default=3,
                   help="1: octave, 3: third octave (default)")
    p.add_argument("--depth", type=DEPTH_M, default=1.0, metavar="M",
                   help="distance of the scan plane in front of the camera (default 1 m)")
    p.add_argument("--grid", type=integer(2, MAX_GRID), default=101, metavar="N",
                   help=f"scan points across each side of the view (default 101; its points "
                        f"x the microphones may take at most {MAX_GRID_BYTES // 2**30} GiB)")
    p.add_argument("--block", type=integer(16, 65_536), default=1024,
                   help="Welch block length, samples (default 1024)")
    p.add_argument("--overlap", type=number(0, 0.95), default=0.5,
                   help="Welch overlap (default 0.5)")
    p.add_argument("--window", type=positive(10, " s"), default=0.1, metavar="S",
                   help="CSM averaging window (default 0.1 s)")
    p.add_argument("--clean-sc", action="store_true", help="deconvolve with CLEAN-SC")
    p.add_argument("--range-db", type=RANGE_DB, default=15.0,
                   help="dynamic range drawn, dB below each map's peak (default 15)")
    p.add_argument("--camera", default="cam0", help="camera drawn on (default cam0)")
    p.add_argument("--fps", type=positive(60, " fps"), default=10.0,
                   help="video frames per second (default 10)")
    p.add_argument("--scale", type=number(0.05, 2),default=0.5,
                   help="video size relative to the camera image (default 0.5)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("live", help="live mode: the boards streaming, acoustic video",
                       description="Enter or leave the daemon's live mode (every board scanning "
                                   "without end, the cameras streaming, the latest seconds "
                                   "kept), record its latest seconds, or write an acoustic "
                                   "video of it or of a recording.")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    start = actions.add_parser("start", help="enter live mode (the daemon must be idle)")
    start.add_argument("--seconds", type=number(1, 30, " s"), default=10.0,
                       help="seconds kept in the ring buffer (default 10)")
    start.add_argument("--camera-fps", type=positive(30, " fps"), default=10.0,
                       help="camera frames per second (default 10)")
    start.add_argument("--camera", action="append", dest="cameras", metavar="NAME",
                       help="a camera to stream (repeat for several; default: all)")
    actions.add_parser("stop", help="leave live mode")
    record = actions.add_parser("record", help="store the latest seconds (session format and "
                                               "Acoular's HDF5 time data)")
    record.add_argument("--seconds", type=positive(30, " s"), default=5.0,
                        help="seconds to store (default 5, at most the ring's)")
    record.add_argument("--no-wait", action="store_true",
                        help="return once the daemon has taken the seconds, before they are "
                             "written (a live_recorded event says when they are)")
    record.add_argument("--write-timeout", type=positive(3600, " s"), default=300.0,
                        metavar="S", help="seconds to wait for the recording to be written "
                                          "(default 300)")
    video = actions.add_parser("video", help="an acoustic video of live mode or of a recording")
    _add_imaging_arguments(video)
    video.add_argument("--recording", type=Path, metavar="DIR",
                       help="a live recording (from `micam live record`) instead of live mode")
    video.add_argument("--seconds", type=positive(3600, " s"), default=10.0,
                       help="from live mode: seconds to film (default 10)")
    for action in actions.choices.values():
        add_client_arguments(action)
        action.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.daemon.client import client_from_args

    if args.action == "video":
        return _video(args)
    with client_from_args(args) as client:
        if args.action == "start":
            status = client.request("live.start", seconds=args.seconds,
                                    camera_fps=args.camera_fps, cameras=args.cameras)
            print(f"live mode: {status['capacity_s']:g} s kept at "
                  f"{status['sample_rate_hz']:g} Hz; `micam live stop` to leave it")
        elif args.action == "stop":
            client.request("live.stop")
            print("live mode left")
        else:
            _record(client, args)
    return 0


def _record(client, args: argparse.Namespace) -> None:
    """`micam live record`: by default it returns once the recording can be read."""
    from contextlib import closing

    if args.no_wait:
        result = client.request("live.record", seconds=args.seconds)
        print(f"recording {result['seconds']:.2f} s into {result['path']} (Acoular: "
              f"{result['acoular_file']}); a live_recorded event says when it is written")
        return
    with closing(client.subscribe()) as events:  # before the request: its event is not missed
        result = client.request("live.record", seconds=args.seconds)
        print(f"recording {result['seconds']:.2f} s into {result['path']} ...", flush=True)
        _wait_written(events, result["path"], args.write_timeout)
    print(f"written: {result['path']} (Acoular: {result['acoular_file']})")


def _wait_written(events, path: str, timeout_s: float) -> None:
    """Until the daemon's `live_recorded` event for `path`; UserError if it says the writing
    failed, or if none comes within `timeout_s`."""
    import time

    from acquisition.contracts.protocol import LiveRecordedEvent

    deadline = time.monotonic() + timeout_s
    while (left := deadline - time.monotonic()) > 0:
        event = events.next(left)
        if isinstance(event, LiveRecordedEvent) and event.path == path:
            if event.error:
                raise UserError(f"the live recording {path} failed: {event.error}")
            return
    raise UserError(f"the daemon did not say within {timeout_s:g} s that {path} is written; "
                    "`micam watch` shows its live_recorded event when it comes")


def _video(args: argparse.Namespace) -> int:
    from imaging.live import LiveSettings
    from imaging.live_frames import VideoFile

    check_outputs(("--out", args.out))
    geometry = geometry_file("--geometry", args.geometry)
    _check_grid(args.grid, geometry.n_mics)
    settings = LiveSettings(band_hz=args.band, fraction=args.fraction,
                            block_size=args.block, overlap=args.overlap,
                            window_s=args.window, depth_m=args.depth,
                            grid_shape=(args.grid, args.grid), camera=args.camera,
                            clean_sc=args.clean_sc, dynamic_range_db=args.range_db,
                            image_scale=args.scale)
    video = VideoFile(args.out, args.fps)
    if args.recording is not None:
        n = _video_of_recording(args.recording, geometry, settings, args.fps, video)
    else:
        n = _video_of_live(args, geometry, settings, video)
    print(f"wrote {args.out}: {n} frames at {args.fps:g} fps")
    return 0


def _check_grid(grid: int, n_mics: int) -> None:
    """Refuse a grid whose imager would take more than MAX_GRID_BYTES (UserError)."""
    need = grid * grid * n_mics * BYTES_PER_POINT_AND_MIC
    if need > MAX_GRID_BYTES:
        fits = math.isqrt(MAX_GRID_BYTES // (n_mics * BYTES_PER_POINT_AND_MIC))
        raise UserError(f"--grid {grid}: {grid} x {grid} points and {n_mics} microphones need "
                        f"about {need / 2**30:.1f} GiB; at most --grid {fits} fits in the "
                        f"{MAX_GRID_BYTES // 2**30} GiB the live imager may take")


def _video_of_recording(path: Path, geometry, settings, fps: float, video) -> int:
    from acquisition.live.record import read_live_recording
    from imaging.live import LiveImager
    from imaging.live_frames import MapFrames, caption_of
    from micam.live_feed import mic_columns

    codes, fs, first, frames, config = read_live_recording(path, settings.camera)
    imager = LiveImager(geometry, settings, fs)
    drawn = MapFrames(imager, fps, caption_of(imager))
    for frame in frames:
        drawn.add_frame(frame.sample, frame.image)
    columns, scale = mic_columns(config.columns, geometry)
    hop = drawn.hop
    with video:
        for start in range(0, codes.shape[0], hop):
            for f in drawn.push(first + start, codes[start: start + hop, columns] * scale):
                video.write(f.image)
    return video.frames


def _video_of_live(args: argparse.Namespace, geometry, settings, video) -> int:
    from acquisition.daemon.client import client_from_args
    from imaging.live import LiveImager
    from imaging.live_frames import MapFrames, caption_of
    from micam.live_feed import LiveFeed

    with client_from_args(args) as client:
        status = client.status()
        if status.live is None:
            raise UserError("the daemon is not in live mode; `micam live start` first, or "
                            "film a recording with --recording")
        imager = LiveImager(geometry, settings, status.live.sample_rate_hz)
        with LiveFeed(client, MapFrames(imager, args.fps, caption_of(imager)),
                      geometry) as feed, video:
            for fed in feed.frames_for(args.seconds):
                video.write(fed.frame.image)
    return video.frames
