"""Options `micam image` and `micam evaluate-imaging` share: the correction of the channels'
responses in the CSM (paper VI: Dougherty's eigenvalue calibration, or the responses of the
calibration result) and a simulated microphone phase error; and the geometry file that they
and `micam live video` read."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from acquisition.contracts.errors import UserError
from .bounded import POSE, SEED, SPEAKER, number


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add --csm-calibration / --responses and --mic-phase-error-deg / -seed to a command."""
    which = p.add_mutually_exclusive_group()
    which.add_argument(
        "--csm-calibration", metavar="POSE:SPEAKER", type=recording,
        help="correct every CSM for the channels' gains and phases estimated from this "
             "recording of one speaker (Dougherty's eigenvalue calibration, paper VI); "
             "evaluate-imaging leaves that recording out of its statistics")
    which.add_argument(
        "--responses", action="store_true",
        help="correct every CSM for the per-microphone responses of the geometry file "
             "(result.json's microphone_responses)")
    p.add_argument(
        "--mic-phase-error-deg", type=number(0, 180, " deg"), default=0.0, metavar="DEG",
        help="simulate microphones that differ in phase: add a per-channel phase, normal with "
             "DEG degrees standard deviation and constant over frequency, to every recording's "
             "spectra (default 0: none)")
    p.add_argument("--mic-phase-error-seed", type=SEED, default=0, metavar="N",
                   help="seed of the simulated phase error (default 0)")


def geometry_file(flag: str, path: Path):
    """The geometry in `path` (`imaging.load_geometry`), read before any work; a
    malformed or oversized file is a UserError naming `flag`, the file and what is wrong."""
    from imaging.geometry import GeometryFileError, load_geometry

    try:
        return load_geometry(path)
    except GeometryFileError as exc:
        raise UserError(f"{flag}: {exc}") from None


def recording(text: str) -> tuple[int, int]:
    """POSE:SPEAKER -> (pose, speaker), each within its range."""
    parts = text.split(":")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not POSE:SPEAKER, e.g. 0:4 (speaker 4 of pose 0)")
    try:
        return POSE(parts[0]), SPEAKER(parts[1])
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{text!r} (POSE:SPEAKER): {exc}") from None


def with_simulated_error(args: argparse.Namespace, settings, n_mics: int):
    """The imaging settings with the --mic-phase-error-deg of the options, if any."""
    from imaging.csm_calibration import simulated_phase_error

    if not args.mic_phase_error_deg:
        return settings
    error = simulated_phase_error(n_mics, args.mic_phase_error_deg, args.mic_phase_error_seed)
    return replace(settings, simulated_error=error)


def corrected_settings(args: argparse.Namespace, reader, geometry, settings):
    """The imaging settings with the options' simulated error and correction, the recordings
    to leave out of an evaluation (the calibration recording), as a set, and the geometry to
    image with (without the microphones' own delays when the responses, which hold them,
    correct the CSM).

    Raises UserError for --responses without responses in the geometry file, and the
    eigenvalue calibration's input errors (CalibrationInputError, SessionError)."""
    from imaging.evaluate import channel_calibration

    settings = with_simulated_error(args, settings, geometry.n_mics)
    if args.responses:
        if geometry.responses is None:
            raise UserError(f"--responses: {args.geometry} has no microphone_responses; "
                            "calibrate with a version that measures them, or use "
                            "--csm-calibration POSE:SPEAKER")
        return (replace(settings, correction=geometry.responses), set(),
                geometry.without_own_delays())
    if args.csm_calibration is not None:
        pose, speaker = args.csm_calibration
        correction = channel_calibration(reader, geometry, pose, speaker, settings)
        return replace(settings, correction=correction), {(pose, speaker)}, geometry
    return settings, set(), geometry
