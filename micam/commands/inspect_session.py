"""`micam inspect SESSION`: what a session holds, whether it is intact, and its ground truth."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from acquisition.contracts.errors import UserError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="summarise a session and check its files",
                       description="Print a session's status, steps and size, and re-check "
                                   "every file against the journal's checksum.")
    p.add_argument("session", type=Path, help="session directory")
    p.set_defaults(run=run)


def _megabytes(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file()) / 1e6


def _mean(points: list[list[float]]) -> list[float]:
    return [sum(axis) / len(points) for axis in zip(*points, strict=True)]


def _norm(v: list[float]) -> float:
    return sum(x * x for x in v) ** 0.5


def _truth_line(path: Path) -> str:
    """The ground truth in one line, or why it cannot be read (it is a file like any other)."""
    try:
        truth = json.loads(path.read_text())
        if "poses" not in truth:  # a truth written by hand: the microphones only
            return f"{len(truth.get('microphones', []))} microphones"
        dist = [_norm(_mean(p["speakers_m"])) for p in truth["poses"]]
        return (f"{len(truth['microphones'])} microphones, c = "
                f"{truth['speed_of_sound_m_s']:.2f} m/s ({truth['temperature_c']:.1f} degC), "
                f"rig centre {min(dist):.2f}-{max(dist):.2f} m from camera 0")
    except (OSError, ValueError, KeyError, TypeError, IndexError, AttributeError) as exc:
        return f"{path.name} is not readable ({type(exc).__name__}: {exc})"


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.capture_config import CaptureConfig
    from acquisition.contracts.rig_description import (
        DESCRIPTION_KIND,
        DescriptionError,
        validate_description,
    )
    from acquisition.contracts.session import SessionError, SessionReader
    from acquisition.contracts.step_ids import REFMIC_STEP, is_pose_step, is_reference_step

    try:
        reader = SessionReader(args.session)
        capture = reader.capture
        if capture.get("kind") == DESCRIPTION_KIND:  # checked before its keys are read
            validate_description(capture, f"session {args.session}: its description")
        else:
            CaptureConfig.of_session(capture, args.session)
    except (SessionError, DescriptionError) as exc:
        raise UserError(str(exc)) from None
    steps = reader.steps()
    poses = [s for s in steps if is_pose_step(s)]
    refs = [s for s in steps if is_reference_step(s)]
    n_files = sum(len(r.files) for r in steps.values())
    print(f"session   {reader.session_id} at {args.session}")
    print(f"status    {reader.status}")
    imported = capture.get("kind") == DESCRIPTION_KIND  # `micam import`: no hardware
    planned = "" if imported else f" of {capture['n_poses']}"
    print(f"steps     {len(refs)} reference recordings, "
          f"{'1' if REFMIC_STEP in steps else 'no'} reference-microphone image set, "
          f"{len(poses)}{planned} poses")
    if imported:
        mics = sum(len(g["columns"]) for g in capture["channels"])
        where = f"{mics} microphones in {len(capture['channels'])} clock/latency groups"
    else:
        where = f"{len(capture['columns'])} on {len(capture['boards'])} boards"
    print(f"channels  {where} at {capture['sample_rate_hz']:.0f} S/s; cameras "
          f"{', '.join(c['name'] for c in capture['cameras'])}"
          f"{' (imported)' if imported else ''}")
    print(f"files     {n_files} ({_megabytes(args.session):.0f} MB)")
    problems = reader.verify()
    print("checksums " + ("all intact" if not problems else f"{len(problems)} problems:"))
    for problem in problems:
        print(f"  - {problem}")
    truth_path = args.session / "truth.json"
    if truth_path.is_file():
        print(f"truth     {_truth_line(truth_path)}")
    return 0 if not problems else 1
