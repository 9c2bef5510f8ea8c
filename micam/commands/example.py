"""`micam example import DIR`: write the worked example of docs/import.md, so that its commands
run as written on a machine with no recordings of its own.

The example is another lab's recorder's output (sim/foreign_lab.py): WAV recordings, PNG
images and `import.toml` describing them, plus `truth.json` (the simulated lab's microphones,
camera, latencies and speed of sound) for `micam calibrate --truth`.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..outputs import check_output_dirs
from .bounded import SEED, integer

MIN_POSES = 4
"""The fewest poses that calibrate: the camera's intrinsics need the board in 4 images."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "example", help="write an example to try a command on",
        description="Write the worked example of the docs into a new directory.")
    what = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    imp = what.add_parser(
        "import", help="another recorder's capture for `micam import` (docs/import.md)",
        description="Write docs/import.md's worked example into DIR: a simulated lab's "
                    "recordings (WAV) and images (PNG) as another recorder leaves them, "
                    "import.toml describing them, and truth.json (the simulated truth, for "
                    "`micam calibrate --truth`).")
    imp.add_argument("dir", type=Path, metavar="DIR", help="a new or empty directory")
    imp.add_argument("--poses", type=integer(MIN_POSES, 100), default=MIN_POSES, metavar="N",
                     help=f"rig poses to record (default and least: {MIN_POSES})")
    imp.add_argument("--seed", type=SEED, default=5, help="the simulated lab's seed (default 5)")
    imp.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sim.foreign_lab import make_world, write_folder

    check_output_dirs(("DIR", args.dir))
    world = make_world(seed=args.seed, n_poses=args.poses)
    toml = write_folder(world, args.dir)
    (args.dir / "truth.json").write_text(json.dumps(world.truth(), indent=2) + "\n")
    print(f"{args.dir}: {args.poses} poses of a 48-microphone lab (docs/import.md, \"A worked "
          f"example\"); import it with `micam import {toml} --out SESSION`")
    return 0
