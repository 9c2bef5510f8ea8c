"""`micam image SESSION --pose N --speaker K --band F --geometry FILE --out map.png`: the
delay-and-sum map and the CLEAN-SC components of one recording, drawn on a camera's image of
that pose over the camera's whole view of the rig plane."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from acquisition.contracts.errors import UserError

from ..outputs import check_outputs
from . import imaging_options
from .bounded import BAND_HZ, FRACTION, POSE, RANGE_DB, SPEAKER, number


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "image",
        help="draw the acoustic maps of one recording on the camera image",
        description="Beamform one speaker recording of a pose on the rig plane through the "
                    "speakers (from the board pose in the geometry file), over everything the "
                    "camera sees of that plane, deconvolve it with CLEAN-SC, and draw the "
                    "delay-and-sum map and the CLEAN-SC components over the camera's image "
                    "of the pose with a colour bar in dB (paper section VI, Fig. 15).",
    )
    p.add_argument("session", type=Path, help="session directory")
    p.add_argument("--geometry", required=True, type=Path, metavar="FILE",
                   help="calibration result.json, or truth.json of a simulated session")
    p.add_argument("--pose", required=True, type=POSE, help="pose number (step pose/NNNN)")
    p.add_argument("--speaker", required=True, type=SPEAKER, help="speaker recording to image")
    p.add_argument("--band", required=True, type=BAND_HZ, metavar="HZ",
                   help="band centre frequency in hertz")
    p.add_argument("--fraction", type=FRACTION, default=12,
                   help="band width as a fraction of an octave (default 12: 1/12 octave)")
    p.add_argument("--camera", default="cam0", help="camera whose image is used (default cam0)")
    p.add_argument("--spacing", type=number(0.0005, 1.0, " m"), default=0.004, metavar="M",
                   help="grid spacing on the rig plane, metres (default 0.004; coarser when "
                        "the camera's view would need more than 120000 points)")
    p.add_argument("--range-db", type=RANGE_DB, default=15.0,
                   help="dynamic range of the maps, dB below each map's peak (default 15)")
    p.add_argument("--steering", default="true location",
                   help="steering formulation: classic, inverse, 'true level', "
                        "'true location' (default), 'paper eq19', 'paper eq20'")
    imaging_options.add_arguments(p)
    p.add_argument("--out", required=True, type=Path, help="PNG file to write")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.session import SessionReader
    from calibration.figures.style import save
    from calibration.report import significant
    from imaging.evaluate import ImagingSettings
    from imaging.figures.recording_map import recording_map

    check_outputs(("--out", args.out))
    geometry = imaging_options.geometry_file("--geometry", args.geometry)
    reader = SessionReader(args.session)
    settings, calibrated_from, geometry = imaging_options.corrected_settings(
        args, reader, geometry, ImagingSettings(fraction=args.fraction,
                                                bands_hz=(args.band,)))
    drawn = recording_map(reader, geometry, args.pose, args.speaker, args.band, settings,
                          args.camera, args.spacing, args.range_db, args.steering)
    save(drawn.figure, args.out)
    print(f"wrote {args.out}; CLEAN-SC peak {significant(1e3 * drawn.error_m)} mm from speaker "
          f"{args.speaker} as the geometry places it (sub-grid; its grid node "
          f"{significant(1e3 * drawn.node_error_m)} mm away on the "
          f"{significant(1e3 * drawn.spacing_m)} mm grid), {drawn.n_components} components")
    if not drawn.speaker_in_view:
        print(f"warning: speaker {args.speaker} is outside {args.camera}'s view at pose "
              f"{args.pose}: the map covers only what {args.camera} sees, so its peak cannot be "
              "at the speaker; image it with a camera that sees it", file=sys.stderr)
    if (args.pose, args.speaker) in calibrated_from:
        print("note: this recording calibrated the channels (--csm-calibration), so its map "
              "fits the speaker's position by construction; image another one to judge it")
    return 0
