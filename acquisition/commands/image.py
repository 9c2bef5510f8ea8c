"""`micam image SESSION --pose N --speaker K --band F --geometry FILE --out map.png`: the
delay-and-sum and CLEAN-SC maps of one recording, drawn on a camera's image of that pose."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import UserError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "image",
        help="draw the acoustic maps of one recording on the camera image",
        description="Beamform one speaker recording of a pose on the rig plane through the "
                    "speakers (from the board pose in the geometry file), deconvolve it with "
                    "CLEAN-SC, and write both maps side by side over the camera's image of the "
                    "pose as a PNG (paper section VI).",
    )
    p.add_argument("session", type=Path, help="session directory")
    p.add_argument("--geometry", required=True, type=Path, metavar="FILE",
                   help="calibration result.json, or truth.json of a simulated session")
    p.add_argument("--pose", required=True, type=int, help="pose number (step pose/NNNN)")
    p.add_argument("--speaker", required=True, type=int, help="speaker recording to image")
    p.add_argument("--band", required=True, type=float, metavar="HZ",
                   help="band centre frequency in hertz")
    p.add_argument("--fraction", type=int, default=12,
                   help="band width as a fraction of an octave (default 12: 1/12 octave)")
    p.add_argument("--camera", default="cam0", help="camera whose image is used (default cam0)")
    p.add_argument("--spacing", type=float, default=0.003, metavar="M",
                   help="grid spacing on the rig plane, metres (default 0.003)")
    p.add_argument("--range-db", type=float, default=15.0,
                   help="dynamic range of the colour layer, dB (default 15)")
    p.add_argument("--steering", default="true location",
                   help="steering formulation: classic, inverse, 'true level', "
                        "'true location' (default), 'paper eq19', 'paper eq20'")
    p.add_argument("--out", required=True, type=Path, help="PNG file to write")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from acquisition.session import SessionError, SessionReader
    from calibration.imaging import (
        CleanScOptions,
        WelchOptions,
        band_bins,
        beamform_csm,
        clean_sc,
        cross_spectra,
        load_geometry,
    )
    from calibration.imaging.evaluate import geometry_steering, mic_signals, rig_grid
    from calibration.imaging.overlay import (
        map_to_image,
        render_overlay,
        spread_components,
        write_png,
    )

    step = f"pose/{args.pose:04d}"
    try:
        reader = SessionReader(args.session)
        geometry = load_geometry(args.geometry)
        pose = geometry.pose(args.pose)
        camera = geometry.camera(args.camera)
        signals, fs = mic_signals(reader, step, f"speaker_{args.speaker}.wav", geometry)
        image = reader.read_image(step, f"{args.camera}.png")
        welch = WelchOptions()
        bins = band_bins(args.band, args.fraction, welch.block_size, fs)
        band = cross_spectra(signals, fs, bins, welch).band_sum(args.band, args.fraction)
        rig_speakers = np.asarray(reader.capture["rig"]["speakers_m"], dtype=np.float64)
        grid = rig_grid(pose, rig_speakers, args.spacing, 0.06)
        steering = geometry_steering(geometry, grid.points, args.steering)
    except (SessionError, ValueError) as exc:
        raise UserError(str(exc)) from None
    h = steering.vectors(args.band)
    power = steering.amplitude**2
    das = np.maximum(beamform_csm(h, band.csm[0], True, power), 0.0)
    clean = clean_sc(band.csm[0], h, CleanScOptions(), power, grid.shape)
    panels = []
    for title, values in (("delay-and-sum", das),
                          ("CLEAN-SC", spread_components(clean.clean_map, grid))):
        layer = map_to_image(values, grid, camera)
        panel = render_overlay(image, layer, args.range_db)
        cv2.putText(panel, f"{title}, {args.band:.0f} Hz 1/{args.fraction} oct, "
                           f"{args.range_db:g} dB", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0,
                    (255, 255, 255), 2, cv2.LINE_AA)
        panels.append(panel)
    write_png(args.out, np.hstack(panels))
    node = int(np.argmax(clean.clean_map))
    error_mm = 1e3 * np.linalg.norm(grid.points[node] - pose.speakers_m[args.speaker])
    print(f"wrote {args.out}; CLEAN-SC peak {error_mm:.1f} mm from speaker {args.speaker} "
          f"({clean.n_iterations} components)")
    return 0
