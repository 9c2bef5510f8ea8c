"""`micam config template NAME` and `micam config check FILE`: configurations to start from,
and a check of a hand-edited one."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition.contracts.errors import UserError

from ..outputs import check_outputs


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "config", help="write a commented starting configuration, or check one",
        description="Write a commented, valid configuration to start from (the daemon on the "
                    "paper's set-up or a smaller rig, or an import of another recorder's "
                    "files), or check a configuration file.")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    t = actions.add_parser("template", help="write a commented starting configuration",
                           description="paper: the daemon on 3 x DT9836 + 6 x DT9816-A + the "
                                       "reference board, 3 cameras; generic: the daemon on a "
                                       "smaller rig, one camera; import: `micam import`.")
    t.add_argument("name", choices=("paper", "generic", "audio", "uma16", "import"),
                   help="paper (the paper's 9 boards, 3 cameras), generic (3 DT9836, one "
                        "camera), audio (one audio interface: 15 microphones, the reference, "
                        "6 speakers), uma16 (a miniDSP UMA-16 USB array and an interface) or "
                        "import (a session from another recorder's files)")
    t.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="write it to FILE (never over an existing file); default: print it")
    t.set_defaults(run=run_template)
    c = actions.add_parser("check", help="validate a daemon configuration or an import file",
                           description="A file with a [recordings] table is checked as an "
                                       "import description, any other as the daemon's.")
    c.add_argument("file", type=Path, help="the daemon configuration or import spec to check")
    c.set_defaults(run=run_check)


def run_template(args: argparse.Namespace) -> int:
    from micam.templates import template

    text = template(args.name)
    if args.out is None:
        print(text, end="")
        return 0
    check_outputs(("--out", args.out))
    if args.out.exists():
        raise UserError(f"{args.out} exists; choose another --out (a configuration is never "
                        "overwritten)")
    try:
        args.out.write_text(text)
    except OSError as exc:
        raise UserError(f"cannot write {args.out}: {exc}") from None
    print(f"{args.out}: the '{args.name}' template; edit what its comments point out, then "
          f"`micam config check {args.out}`")
    return 0


def run_check(args: argparse.Namespace) -> int:
    """Check the file as read once (it may be a pipe: `micam config check <(...)`)."""
    from acquisition.contracts.bounded_files import read_toml
    from micam.daemon import check_config
    from micam.hardware import daemon_config_of

    from micam.templates import PLACEHOLDER

    document = read_toml(args.file, "configuration", UserError)
    unedited = placeholders(document, PLACEHOLDER)
    if unedited:
        raise UserError(f"config file {args.file}: still the template's {PLACEHOLDER} at "
                        f"{', '.join(unedited)}; put this lab's values there (the comment "
                        "beside each says where to find them)")
    if "recordings" in document:
        return _check_import(document, args.file)
    print(check_config(daemon_config_of(document, f"config file {args.file}")))
    return 0


def placeholders(value: object, mark: str, where: str = "") -> list[str]:
    """Where (dotted keys) a template's placeholder `mark` is still in a TOML document."""
    if isinstance(value, str):
        return [where or "the top level"] if mark in value else []
    if isinstance(value, dict):
        return [w for key, item in value.items()
                for w in placeholders(item, mark, f"{where}.{key}".lstrip("."))]
    if isinstance(value, list):
        return [w for n, item in enumerate(value)
                for w in placeholders(item, mark, f"{where}[{n}]")]
    return []


def _check_import(document: dict, path: Path) -> int:
    """Validate an import description's document, as `micam import` will."""
    from pydantic import ValidationError

    from acquisition.contracts.rig_description import problem_text
    from acquisition.importer import ImportSpec

    try:
        spec = ImportSpec.model_validate(document)
    except ValidationError as exc:
        raise UserError(problem_text(f"import description {path}", exc, ImportSpec)
                        .rstrip("\n")) from None
    print(f"import description OK: {len(spec.recordings.poses)} poses, "
          f"{len(spec.microphones())} microphones, {spec.n_speakers} speakers; check its "
          f"files with `micam import {path} --out DIR --check`")
    return 0
