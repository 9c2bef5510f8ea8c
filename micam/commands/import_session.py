"""`micam import SPEC.toml --out DIR`: a micam session from any recorder's files."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition.contracts.errors import UserError

from ..outputs import check_output_dirs


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import", help="build a session from a folder of recordings, images and one TOML file",
        description="Build a micam session (journal, checksums) from recordings (WAV, FLAC, "
                    "RF64, HDF5 time data as Acoular writes it), images and one TOML file that "
                    "describes the rig, the array and the recordings (docs/import.md; "
                    "`micam config template import` writes a starting point).")
    p.add_argument("spec", type=Path, metavar="SPEC.toml",
                   help="the import description; its paths are relative to its folder")
    p.add_argument("--out", type=Path, required=True, metavar="DIR",
                   help="the new session directory (must not exist, or be empty; it is "
                        "written only when the whole import succeeds)")
    p.add_argument("--check", action="store_true",
                   help="check the description and every file, write nothing")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from acquisition.importer import ImportSpecError, check_import, import_session
    from acquisition.contracts.session import SessionError

    check_output_dirs(("--out", args.out))
    try:
        if args.check:
            p = check_import(args.spec)
            print(f"{args.spec}: valid; {len(p.spec.recordings.poses)} poses, "
                  f"{len(p.spec.microphones())} microphones, {p.spec.n_speakers} speakers, "
                  f"{p.n_images} images; every file checked as the import would")
            return 0
        out = import_session(args.spec, args.out, on_step=lambda step: print(f"  {step}"))
    except (ImportSpecError, SessionError) as exc:
        raise UserError(str(exc)) from None
    print(f"session {out}\ncalibrate it with: micam calibrate {out} --out result.json")
    return 0
