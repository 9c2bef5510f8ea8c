"""`micam evaluate-imaging SESSION --geometry FILE`: how well CLEAN-SC maps locate the rig's
speakers in every recording of a session (paper VI-A)."""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

from tqdm import tqdm

from ..errors import UserError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate-imaging",
        help="localization error of CLEAN-SC maps against the speakers' positions",
        description="For every speaker recording of every pose, locate the speaker with "
                    "CLEAN-SC on the rig plane in each 1/N-octave band and report the error "
                    "against its position from the geometry file (mean, median, 95th "
                    "percentile, by distance and by band).",
    )
    p.add_argument("session", type=Path, help="session directory")
    p.add_argument("--geometry", required=True, type=Path, metavar="FILE",
                   help="calibration result.json, or truth.json of a simulated session")
    p.add_argument("--band-lo", type=float, default=5000.0, help="lowest band centre, Hz")
    p.add_argument("--band-hi", type=float, default=15000.0, help="highest band centre, Hz")
    p.add_argument("--fraction", type=int, default=12, help="bands of 1/N octave (default 12)")
    p.add_argument("--spacing", type=float, default=0.006, metavar="M",
                   help="grid spacing on the rig plane, metres (default 0.006, the paper's)")
    p.add_argument("--aligned-grid", action="store_true",
                   help="put grid nodes on the speakers' rig coordinates instead of a random "
                        "sub-cell shift per pose")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the summary as JSON")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes the poses are shared over (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def _line(label: str, s) -> str:
    return (f"{label:>22}  {s.count:6d}  {1e3 * s.mean_m:8.2f}  {1e3 * s.median_m:8.2f}  "
            f"{1e3 * s.p95_m:8.2f}  {1e3 * s.mean_node_m:10.2f}")


def run(args: argparse.Namespace) -> int:
    from acquisition.session import SessionError, SessionReader
    from calibration.imaging import load_geometry
    from calibration.imaging.evaluate import ImagingSettings, evaluate_session

    try:
        reader = SessionReader(args.session)
        geometry = load_geometry(args.geometry)
        settings = ImagingSettings(fraction=args.fraction, band_lo_hz=args.band_lo,
                                   band_hi_hz=args.band_hi, spacing_m=args.spacing,
                                   offset_seed=None if args.aligned_grid else 0)
        settings.band_centres()
        with tqdm(unit="rec", disable=args.quiet, desc="imaging") as bar:
            def progress(done: int, total: int) -> None:
                bar.total = total
                bar.update(done - bar.n)

            result = evaluate_session(reader, geometry, settings, progress, args.workers)
    except (SessionError, ValueError, RuntimeError) as exc:  # RuntimeError: a worker died
        raise UserError(str(exc)) from None
    header = f"{'':>22}  {'n':>6}  {'mean':>8}  {'median':>8}  {'p95':>8}  {'mean@node':>10}"
    print(f"CLEAN-SC localization error, mm (sub-grid peak; 'mean@node' = grid node, "
          f"{1e3 * args.spacing:g} mm grid)")
    print(header)
    print(_line("all", result.overall()))
    for (lo, hi), s in result.by_distance().items():
        print(_line(f"{lo:.1f}-{hi:.1f} m" if math.isfinite(hi) else f">= {lo:.1f} m", s))
    for band, s in result.by_band().items():
        print(_line(f"{band:.0f} Hz", s))
    if args.json:
        tmp = args.json.with_name(args.json.name + ".partial")
        tmp.write_text(json.dumps(result.to_json(), indent=1))
        os.replace(tmp, args.json)
    return 0
