"""`micam evaluate-imaging SESSION (--geometry FILE | --folds K)`: how well CLEAN-SC maps
locate the rig's speakers in every recording of a session (paper VI-A), with a given
calibration (in-sample when it was calibrated from the same session) or k-fold held-out."""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

from acquisition.contracts.errors import UserError

from ..cluster import cluster_map
from ..outputs import check_outputs
from . import imaging_options
from .bounded import BAND_HZ, FRACTION, integer, number

if TYPE_CHECKING:
    from imaging.evaluate import Evaluation, Summary


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate-imaging",
        help="localization error of CLEAN-SC maps against the speakers' positions",
        description="For every speaker recording of every pose, locate the speaker with "
                    "CLEAN-SC on the rig plane in each 1/N-octave band and report the error "
                    "against its position as the camera places it (mean, median, 95th "
                    "percentile, by distance and by band). With --geometry the calibration "
                    "is given; with --folds K the session is calibrated K times, each time "
                    "without one fold of its poses, which are imaged with that calibration "
                    "(held-out), and beside it with the calibration from all poses "
                    "(in-sample).",
    )
    p.add_argument("session", type=Path, help="session directory")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("--geometry", type=Path, metavar="FILE",
                        help="calibration result.json, or truth.json of a simulated session")
    source.add_argument("--folds", type=integer(2, 100), metavar="K",
                        help="calibrate the session itself and report held-out (K folds of "
                             "poses) beside in-sample localization")
    p.add_argument("--truth", type=Path, default=None, metavar="FILE",
                   help="truth.json to measure errors against the true speaker positions too "
                        "(default: SESSION/truth.json if present)")
    p.add_argument("--band-lo", type=BAND_HZ, default=5000.0, help="lowest band centre, Hz")
    p.add_argument("--band-hi", type=BAND_HZ, default=15000.0, help="highest band centre, Hz")
    p.add_argument("--fraction", type=FRACTION, default=12, help="bands of 1/N octave (default 12)")
    p.add_argument("--spacing", type=number(0.002, 0.1, " m"), default=0.006, metavar="M",
                   help="grid spacing on the rig plane, metres (default 0.006, the paper's)")
    p.add_argument("--aligned-grid", action="store_true",
                   help="put grid nodes on the speakers' rig coordinates instead of a random "
                        "sub-cell shift per pose")
    imaging_options.add_arguments(p)
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the summary as JSON")
    p.add_argument("--figure", type=Path, metavar="FILE",
                   help="also draw the errors by band and their distribution as a PNG")
    p.add_argument("--workers", type=integer(1, 256), default=None, metavar="N",
                   help="processes the poses are shared over (default: all cores)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the work as tasks on this Dask scheduler, e.g. tcp://HOST:8786, "
                        "whose workers see SESSION at the same path: with --folds a task per "
                        "calibration (and the imaging of its poses), else a task per pose "
                        "(see docs/batch.md)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def _cells(s: Summary, truth: bool) -> str:
    cells = f"{s.count:6d}  {1e3 * s.mean_m:7.3f}  {1e3 * s.median_m:7.3f}  {1e3 * s.p95_m:7.3f}"
    if truth:
        cells += f"  {1e3 * s.truth_mean_m:7.3f}" if s.truth_mean_m is not None else "        -"
    return cells


def _label(key: float | tuple[float, float]) -> str:
    if isinstance(key, tuple):
        lo, hi = key
        return f"{lo:.1f}-{hi:.1f} m" if math.isfinite(hi) else f">= {lo:.1f} m"
    return f"{key:.0f} Hz"


def table(columns: Mapping[str, Evaluation], spacing_m: float) -> list[str]:
    """The printed summary: one block of columns per evaluation (in-sample, held-out...),
    rows for all recordings, each distance class and each band."""
    evaluations = list(columns.values())
    truth = evaluations[0].overall().truth_mean_m is not None
    width = 33 + (9 if truth else 0)
    head = "  ".join(f"{name:^{width}}" for name in columns)
    sub = "  ".join(f"{'n':>6}  {'mean':>7}  {'median':>7}  {'p95':>7}"
                    + (f"  {'truth':>7}" if truth else "") for _ in columns)
    lines = [
        "CLEAN-SC localization error, mm: the sub-grid peak's distance from the speaker as "
        "the camera places it" + ("; truth: mean distance from the true speaker position"
                                  if truth else ""),
        "distance classes: the rig's pattern centre from camera 0 (as simulate --distance)",
        f"{'':>14}  {head}", f"{'':>14}  {sub}",
        f"{'all':>14}  " + "  ".join(_cells(e.overall(), truth) for e in evaluations)]
    for distance in evaluations[0].by_distance():
        lines.append(f"{_label(distance):>14}  " + "  ".join(
            _cells(e.by_distance()[distance], truth) for e in evaluations))
    for band in evaluations[0].by_band():
        lines.append(f"{_label(band):>14}  " + "  ".join(
            _cells(e.by_band()[band], truth) for e in evaluations))
    nodes = ", ".join(f"{name} {1e3 * e.overall().mean_node_m:.2f}"
                      for name, e in columns.items())
    lines.append(f"at the grid nodes (the paper's measure): mean {nodes} mm, the "
                 f"{1e3 * spacing_m:g} mm grid's own quantization (about 0.38 x spacing "
                 "in every band)")
    return lines


def _write_json(path: Path, document: dict) -> None:
    from acquisition.contracts.session import write_atomic

    text = json.dumps(document, indent=1).encode()
    write_atomic(path, lambda fh: fh.write(text), replace=True)


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.session import SessionReader
    from calibration.figures.style import save
    from imaging.evaluate import ImagingSettings, evaluate_session
    from imaging.figures.evaluation import localization_figure
    from imaging.holdout import cross_validate

    check_outputs(("--json", args.json), ("--figure", args.figure))
    truth_path = args.truth or (args.session / "truth.json")
    if args.truth is not None and not truth_path.is_file():
        raise UserError(f"--truth {truth_path} is not a file")
    if args.folds is not None and (args.responses or args.csm_calibration is not None):
        raise UserError("--responses and --csm-calibration need one calibration: use them "
                        "with --geometry, not --folds")
    truth = (imaging_options.geometry_file("--truth", truth_path) if truth_path.is_file()
             else None)
    geometry = (imaging_options.geometry_file("--geometry", args.geometry)
                if args.geometry is not None else None)
    if args.scheduler is not None and args.workers is not None:
        raise UserError("--workers is the processes of this machine; with --scheduler the "
                        "cluster's workers do the work")
    if args.scheduler is not None:  # the workers may run in another directory
        args.session = args.session.absolute()
    reader = SessionReader(args.session)
    settings = ImagingSettings(fraction=args.fraction, band_lo_hz=args.band_lo,
                               band_hi_hz=args.band_hi, spacing_m=args.spacing,
                               offset_seed=None if args.aligned_grid else 0)
    settings.band_centres()
    with (cluster_map("imaging", args.scheduler, None) as mapper,
          tqdm(unit="rec", disable=args.quiet, desc="imaging") as bar):
        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        if args.folds is not None:
            n_mics = sum(c["role"] == "mic" for c in reader.capture["columns"])
            settings = imaging_options.with_simulated_error(args, settings, n_mics)
            cv = cross_validate(args.session, args.folds, settings, truth=truth,
                                progress=progress, workers=args.workers, mapper=mapper)
            columns = {"in-sample": cv.in_sample, f"held-out ({args.folds} folds)":
                       cv.held_out}
            document = cv.to_json()
        else:
            settings, skip, geometry = imaging_options.corrected_settings(
                args, reader, geometry, settings)
            result = evaluate_session(reader, geometry, settings, progress, args.workers,
                                      skip=skip, truth=truth, mapper=mapper)
            columns = {"given calibration": result}
            document = result.to_json()
    for line in table(columns, args.spacing):
        print(line)
    if settings.simulated_error is not None:
        print(f"with {settings.simulated_error.source}")
    if settings.correction is not None:
        print(f"CSM corrected by the {settings.correction.source}")
    if args.json:
        _write_json(args.json, document)
    if args.figure:
        save(localization_figure(columns, f"CLEAN-SC localization, {reader.session_id}"),
             args.figure)
    return 0
