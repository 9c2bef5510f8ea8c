"""`micam calibrate SESSION --out result.json`: microphone coordinates in the camera-0 frame."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from acquisition.contracts.errors import UserError
from calibration.choices import DEFAULT_LATENCY, LATENCY_MODELS, STAGES

from ..calibrating import calibrate_session
from .bounded import number, positive


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate", help="calibrate cameras, speakers, c and microphones from a session",
        description="Turn a capture session into camera intrinsics, speaker positions, times "
                    "of flight, the speed of sound and every microphone's position in the "
                    "frame of camera 0, with uncertainties and a report.")
    p.add_argument("session", type=Path, help="session directory")
    p.add_argument("--out", type=Path, required=True, help="result file (JSON)")
    p.add_argument("--report", type=Path, default=None,
                   help="directory for report.md and its pictures (default: beside --out)")
    p.add_argument("--acoular-xml", type=Path, default=None,
                   help="also write the geometry in Acoular's MicGeom XML format, "
                        "microphone k as \"Point k\" in id order")
    p.add_argument("--acoular-calib", type=Path, default=None, metavar="FILE",
                   help="also write the microphones' relative sensitivities in Acoular's "
                        "calibration XML format (acoular.Calib)")
    add_calibration_options(p)
    p.add_argument("--truth", type=Path, default=None,
                   help="a micam truth file to compare with: microphones [{id, position_m}], "
                        "speed_of_sound_m_s, cameras [{name, K}] (default: SESSION/truth.json "
                        "if present)")
    p.add_argument("--force", action="store_true", help="overwrite an existing result file")
    p.set_defaults(run=run)


def add_calibration_options(p: argparse.ArgumentParser) -> None:
    """The options of the calibration itself (not of its outputs), with their bounds."""
    p.add_argument("--method", choices=("micam", "paper"), default="micam",
                   help="micam (default) or the paper's coordinate search (baseline)")
    p.add_argument("--latency", choices=LATENCY_MODELS, default=DEFAULT_LATENCY,
                   help="fit one latency per board (default), one for all, or none")
    p.add_argument("--speed-of-sound", choices=("reference", "solve"), default="reference",
                   help="fix c at the reference-microphone fit (default) or solve for it")
    p.add_argument("--refine-poses", action="store_true",
                   help="fit a rigid correction per rig pose, weighted by the camera")
    p.add_argument("--no-joint", action="store_true",
                   help="skip the final joint fit of cameras and array (optical-acoustic "
                        "bundle adjustment) and report the camera-frozen solution")
    p.add_argument("--prior", type=Path, default=None, metavar="FILE",
                   help="a known geometry of the array in its own frame (result.json, "
                        "truth.json or Acoular XML naming microphone k \"Point k\"): fit its "
                        "rigid transform into the camera frame (paper IV-H)")
    p.add_argument("--prior-std-mm", type=positive(1000, " mm"), default=None,
                   help="let each microphone deviate from the prior by about this much "
                        "(default: the prior is rigid)")
    p.add_argument("--layout", type=Path, default=None, metavar="FILE",
                   help="the array's nominal layout (same formats as --prior), only to check "
                        "the wiring against: swapped microphone cables and a column map off "
                        "by a board are found and relabelled (default: --prior's, if given, "
                        "else the session description's [layout]; this replaces it)")
    p.add_argument("--layout-tolerance-mm", type=positive(1000, " mm"), default=None,
                   help="how far a microphone may lie from its nominal place (default: the "
                        "layout's own, else 5)")
    p.add_argument("--temperature", type=number(-40, 60, " degC"), default=None, metavar="DEGC",
                   help="the air temperature measured during the session, degC (with "
                        "--temperature-std); replaces the session's own")
    p.add_argument("--temperature-std", type=number(0, 20, " K"), default=None, metavar="K",
                   help="its standard deviation, kelvin")
    p.add_argument("--humidity", type=number(0, 1), default=None, metavar="RH",
                   help="the relative humidity measured with --temperature, 0..1 (with "
                        "--humidity-std); without it any humidity is assumed possible "
                        "(about +-0.6 m/s at 20 degC)")
    p.add_argument("--humidity-std", type=number(0, 1), default=None, metavar="RH",
                   help="its standard deviation, 0..1")
    p.add_argument("--known-speed-of-sound", type=number(300, 380, " m/s"), default=None,
                   metavar="M_S",
                   help="a measured speed of sound, m/s (with --known-speed-of-sound-std)")
    p.add_argument("--known-speed-of-sound-std", type=number(0, 20, " m/s"), default=None,
                   metavar="M_S",
                   help="its standard deviation, m/s")
    p.add_argument("--intrinsics", action="append", default=[], metavar="CAMERA=FILE",
                   help="a known calibration of a camera (OpenCV YAML/JSON/XML, ROS "
                        "camera_info or a micam result.json); repeat per camera")
    p.add_argument("--intrinsics-use", choices=("fixed", "prior"), default="fixed",
                   help="use --intrinsics as given (default) or as a prior weighted by the "
                        "file's standard deviations (a micam result.json has them)")
    p.add_argument("--weighting", choices=("auto", "compact", "matched", "phat"),
                   default="auto",
                   help="spectral weighting of the TOF correlations: auto (default: compact, "
                        "or matched where the recordings show no reflection), compact "
                        "(robust to early reflections), matched (maximum likelihood in free "
                        "field) or phat (GCC-PHAT)")
    p.add_argument("--allow-interrupted", action="store_true",
                   help="calibrate the completed poses of an interrupted session")


class _OptionsParser(argparse.ArgumentParser):
    """A parser whose errors are `UserError`s (argparse's own would exit the process)."""

    def error(self, message: str):  # type: ignore[override]
        raise UserError(f"calibrate options: {message}")


def calibration_options(argv: Sequence[str] = ()) -> dict[str, object]:
    """The calibration options (`add_calibration_options`) written in `argv`, e.g.
    ["--latency", "common"], by name ("latency"), the others at their defaults.

    Raises:
        UserError: an option that is not one of them, or a value it does not take.
    """
    parser = _OptionsParser(prog="micam calibrate", add_help=False)
    add_calibration_options(parser)
    return vars(parser.parse_args(list(argv)))


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from calibration.report import summary_lines

    bars: list[tqdm] = []  # the bar starts with the first stage, after the checks

    def on_stage(name: str) -> None:
        if not bars:
            bars.append(tqdm(total=len(STAGES), unit="stage", desc="calibrate"))
        bars[0].set_postfix_str(name)
        bars[0].n = STAGES.index(name)
        bars[0].refresh()

    try:
        done = calibrate_session(args, on_stage)
        for bar in bars:
            bar.n = len(STAGES)
    finally:
        for bar in bars:
            bar.close()
    for finding in done.run.result.findings:
        print(f"micam: finding: {finding.line()}", file=sys.stderr)
    for line in summary_lines(done.run, done.truth):
        print(line)
    print(f"result: {args.out}\nreport: {done.report}")
    return 0
