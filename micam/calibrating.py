"""What `micam calibrate` does to one session, shared by `micam calibrate` and `micam batch`.

The checks of its options against the session (a prior geometry, the known air, known camera
intrinsics, the truth file), each raising a `UserError` that names the option, before any work.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition.contracts.errors import UserError


def _prior(args: argparse.Namespace):
    """The --prior geometry in the session's microphone order (checked before any work)."""
    if args.prior is None:
        if args.prior_std_mm is not None:
            raise UserError("--prior-std-mm needs --prior")
        return None
    from calibration.result import PriorFileError, load_prior_positions
    from calibration.session_data import load_session
    from calibration.solver import PriorGeometry

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


_AIR_FLAGS = {"temperature_c": "--temperature", "temperature_std_c": "--temperature-std",
              "relative_humidity": "--humidity", "relative_humidity_std": "--humidity-std",
              "speed_of_sound_m_s": "--known-speed-of-sound",
              "speed_of_sound_std_m_s": "--known-speed-of-sound-std"}


def _known_air(args: argparse.Namespace) -> tuple[float, float] | None:
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


def _report_dir(out: Path) -> Path:
    """The report's directory when --report is not given: beside the result."""
    return out.parent / (out.stem + "-report")
