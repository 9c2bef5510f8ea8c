"""`micam calibrate SESSION --out result.json`: microphone coordinates in the camera-0 frame."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition.contracts.errors import UserError

from ..calibrating import _known_air, _known_intrinsics, _prior, _report_dir, _truth
from ..outputs import check_output_dirs, check_outputs
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
    p.add_argument("--method", choices=("micam", "paper"), default="micam",
                   help="micam (default) or the paper's coordinate search (baseline)")
    p.add_argument("--latency", choices=("per_board", "common", "none"), default="per_board",
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
    p.add_argument("--truth", type=Path, default=None,
                   help="a micam truth file to compare with: microphones [{id, position_m}], "
                        "speed_of_sound_m_s, cameras [{name, K}] (default: SESSION/truth.json "
                        "if present)")
    p.add_argument("--force", action="store_true", help="overwrite an existing result file")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from calibration.pipeline import CalibrationOptions, calibrate
    from calibration.report import summary_lines, write_report
    from calibration.result import write_acoular_calib_xml, write_acoular_xml
    from calibration.session_data import load_session

    out: Path = args.out
    check_outputs(("--out", out), ("--acoular-xml", args.acoular_xml),
                  ("--acoular-calib", args.acoular_calib))
    if out.exists() and not args.force:
        raise UserError(f"{out} exists; choose another --out or pass --force to overwrite it")
    check_output_dirs(("--report", args.report or _report_dir(out)), reuse=True)
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
        prior=prior, speed_of_sound_prior=_known_air(args),
        intrinsics=_known_intrinsics(args, data) or None)
    stages = ["load", "cameras", "speakers", "times of flight", "solver", "dispersion",
              "joint fit", "responses"]
    with tqdm(total=len(stages), unit="stage", desc="calibrate") as bar:
        def on_stage(name: str) -> None:
            bar.set_postfix_str(name)
            bar.n = stages.index(name)
            bar.refresh()

        run_ = calibrate(args.session, options, on_stage)  # input errors are UserErrors
        bar.n = len(stages)
        bar.refresh()
    run_.result.write(out)
    report = write_report(run_, args.report or _report_dir(out), truth,
                          None if prior is None else prior.positions_m)
    if args.acoular_xml is not None:
        write_acoular_xml(run_.result, args.acoular_xml)
    if args.acoular_calib is not None:
        write_acoular_calib_xml(run_.result, args.acoular_calib)
    for line in summary_lines(run_, truth):
        print(line)
    print(f"result: {out}\nreport: {report}")
    return 0
