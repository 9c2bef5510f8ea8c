"""What `micam calibrate` does to one session, shared by `micam calibrate` and `micam batch`.

`calibrate_session` takes the options of `micam calibrate` (micam/commands/calibrate.py
declares them), checks them against the session (each problem a `UserError` naming the option,
before any work), calibrates, and writes result.json, and the report and Acoular files when
asked. Both commands call it, so a batch's result.json is the one `micam calibrate` writes for
the same session and options.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from acquisition.contracts.errors import UserError

from .outputs import check_output_dirs, check_outputs

if TYPE_CHECKING:
    from calibration.pipeline import CalibrationRun
    from kernel.air import SpeedOfSoundPrior


def _prior(args: argparse.Namespace):
    """The --prior geometry in the session's microphone order (checked before any work)."""
    if args.prior is None:
        if args.prior_std_mm is not None:
            raise UserError("--prior-std-mm needs --prior")
        return None
    from calibration.result import PriorFileError, load_prior_positions
    from calibration.session_data import load_session
    from calibration.solve.solver import PriorGeometry

    if args.method == "paper":
        raise UserError("--prior works with --method micam only (the paper's search has none)")
    if args.prior_std_mm is not None and args.prior_std_mm <= 0:
        raise UserError("--prior-std-mm must be positive")
    data = load_session(args.session, args.allow_interrupted)
    try:
        positions = load_prior_positions(args.prior, data.mic_ids)
    except PriorFileError as exc:
        raise UserError(f"--prior: {exc}") from None
    std = None if args.prior_std_mm is None else args.prior_std_mm / 1000.0
    return PriorGeometry(positions, std)


def _layout(args: argparse.Namespace, data):
    """The nominal layout the wiring is checked against, given on the command line: --layout,
    else --prior (None: neither; the calibration then takes the session description's, if it
    has one), by the session's microphone ids. Says on stderr when it replaces the
    description's."""
    from calibration.checks.layout_check import NominalLayout
    from calibration.result import PriorFileError, load_prior_positions

    flag, path = ("--layout", args.layout) if args.layout is not None else ("--prior", args.prior)
    described = data.description.layout
    if path is None:
        if args.layout_tolerance_mm is not None and described is None:
            raise UserError("--layout-tolerance-mm needs --layout, --prior or a [layout] in "
                            "the session's description")
        return None
    try:
        positions = load_prior_positions(path, data.mic_ids)
    except PriorFileError as exc:
        raise UserError(f"{flag}: {exc}") from None
    if described is not None:
        print(f"micam: {flag} {path} replaces the nominal layout in the session's description",
              file=sys.stderr)
    return NominalLayout(data.mic_ids, positions)


_AIR_FLAGS = {"temperature_c": "--temperature", "temperature_std_c": "--temperature-std",
              "relative_humidity": "--humidity", "relative_humidity_std": "--humidity-std",
              "speed_of_sound_m_s": "--known-speed-of-sound",
              "speed_of_sound_std_m_s": "--known-speed-of-sound-std"}


def _known_air(args: argparse.Namespace) -> SpeedOfSoundPrior | None:
    """The known (c, std) of --temperature or --known-speed-of-sound, checked."""
    from pydantic import ValidationError

    from acquisition.contracts.rig_description import KnownAir

    given = {key: getattr(args, flag[2:].replace("-", "_"))
             for key, flag in _AIR_FLAGS.items()}
    given = {k: v for k, v in given.items() if v is not None}
    if not given:
        return None
    for value, std in (("temperature_c", "temperature_std_c"),
                       ("relative_humidity", "relative_humidity_std"),
                       ("speed_of_sound_m_s", "speed_of_sound_std_m_s")):
        if (value in given) != (std in given):
            raise UserError(f"{_AIR_FLAGS[value]} and {_AIR_FLAGS[std]} go together: write the "
                            "measured value and how well it is known")
    if "temperature_c" in given and "speed_of_sound_m_s" in given:
        raise UserError("--temperature and --known-speed-of-sound: write only the one you "
                        "measured")
    try:
        return KnownAir.model_validate(given).speed_of_sound_prior()
    except ValidationError as exc:
        problems = [f"{_AIR_FLAGS.get(str(e['loc'][0]), e['loc'][0])}: {e['msg']}"
                    for e in exc.errors()]
        raise UserError("; ".join(problems)) from None


def _known_intrinsics(args: argparse.Namespace, data) -> dict:
    """--intrinsics CAMERA=FILE, read for the session's cameras."""
    from acquisition.intrinsics_file import IntrinsicsFileError, read_intrinsics

    sizes = {c.name: (c.width, c.height) for c in data.description.cameras}
    known = {}
    for item in args.intrinsics:
        camera, sep, file = item.partition("=")
        if not sep or not file:
            raise UserError(f"--intrinsics {item!r}: write CAMERA=FILE, e.g. cam0=cam0.yaml")
        if camera not in sizes:
            raise UserError(f"--intrinsics {item!r}: the session has no camera {camera!r} (it "
                            f"has {', '.join(sizes)}); write one of those names")
        try:
            known[camera] = read_intrinsics(Path(file), camera, sizes[camera],
                                            args.intrinsics_use)
        except IntrinsicsFileError as exc:
            raise UserError(f"--intrinsics {item!r}: {exc}") from None
    return known


def _truth(args: argparse.Namespace, data) -> dict | None:
    """The truth file, checked against the session before any work (None: there is none)."""
    from calibration.truth import TruthError, load_truth

    path = args.truth or (args.session / "truth.json")
    if args.truth is not None and not path.is_file():
        raise UserError(f"--truth {path} is not a file")
    if not path.is_file():
        return None
    try:
        return load_truth(path, [int(i) for i in data.mic_ids], list(data.camera_names))
    except TruthError as exc:
        flag = "--truth" if args.truth is not None else "the session's truth.json"
        raise UserError(f"{flag}: {exc}") from None


def default_report_dir(out: Path) -> Path:
    """The report's directory when --report is not given: beside the result."""
    return out.parent / (out.stem + "-report")


@dataclass(frozen=True)
class Calibrated:
    """What `calibrate_session` made: the run, the truth it was compared with (None: none)
    and the report's directory (None: not written)."""

    run: CalibrationRun
    truth: dict | None
    report: Path | None


def calibrate_session(args: argparse.Namespace, on_stage: Callable[[str], None] | None = None,
                      report: bool = True) -> Calibrated:
    """`micam calibrate`'s work on `args.session`: check the outputs and the options, calibrate
    (telling `on_stage` each stage's name), write `args.out` (result.json) and, with `report`,
    the report (`args.report`, default beside `args.out`), then the Acoular files asked for.

    Raises:
        UserError: an output that cannot be written, an option that does not fit the session,
            a session that cannot be calibrated; nothing is written then.
    """
    from calibration.pipeline import CalibrationOptions, calibrate
    from calibration.report import write_report
    import numpy as np

    from calibration.result import (
        load_prior_positions,
        write_acoular_calib_xml,
        write_acoular_xml,
    )
    from calibration.session_data import load_session

    out: Path = args.out
    check_outputs(("--out", out), ("--acoular-xml", args.acoular_xml),
                  ("--acoular-calib", args.acoular_calib))
    if out.exists() and not args.force:
        raise UserError(f"{out} exists; choose another --out or pass --force to overwrite it")
    report_dir = (args.report or default_report_dir(out)) if report else None
    check_output_dirs(("--report", report_dir), reuse=True)
    if args.acoular_calib is not None and (args.no_joint or args.method == "paper"):
        raise UserError("--acoular-calib needs the joint fit (it estimates the responses); "
                        "leave out --no-joint and --method paper")
    data = load_session(args.session, args.allow_interrupted)
    truth = _truth(args, data)
    prior = _prior(args)
    options = CalibrationOptions(
        method=args.method, latency=args.latency, speed_of_sound=args.speed_of_sound,
        refine_poses=args.refine_poses, weighting=args.weighting,
        allow_interrupted=args.allow_interrupted, joint=not args.no_joint,
        prior=prior, layout=_layout(args, data),
        layout_tolerance_m=(None if args.layout_tolerance_mm is None
                            else args.layout_tolerance_mm / 1000.0),
        speed_of_sound_prior=_known_air(args),
        intrinsics=_known_intrinsics(args, data) or None)
    run = calibrate(args.session, options, on_stage)  # input errors are UserErrors
    run.result.write(out)
    if report_dir is not None:
        # the prior in the result's microphone order (the calibration may have relabelled
        # columns or left microphones out)
        ids = np.array([m.id for m in run.result.microphones])
        prior_m = None if prior is None else load_prior_positions(args.prior, ids)
        report_dir = write_report(run, report_dir, truth, prior_m)
    if args.acoular_xml is not None:
        write_acoular_xml(run.result, args.acoular_xml)
    if args.acoular_calib is not None:
        write_acoular_calib_xml(run.result, args.acoular_calib)
    return Calibrated(run, truth, report_dir)
