"""`micam install udev|systemd`: the udev rules and systemd units shipped in the package,
written where udev and systemd read them, with what was written printed."""

from __future__ import annotations

import argparse
import textwrap
import shutil
import sys
from pathlib import Path

from acquisition.contracts.errors import UserError

from ..data import shipped

UDEV_DIR = Path("etc/udev/rules.d")
SYSTEMD_DIR = Path("etc/systemd/system")
UDEV_FLAG = "60-micam-daq.rules"
UDEV_ACCESS = {"uaccess": "61-micam-daq-uaccess.rules", "plugdev": "61-micam-daq-plugdev.rules"}
UNITS = ("micam-daemon.service", "micam-web.service")
MICAM_TOKEN = "@MICAM@"
"""Where a unit names the micam executable; replaced by the installed one's path."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "install", help="install the udev rules or the systemd units shipped with micam",
        description="Write the files shipped in the package (micam/data/) where udev or systemd "
                    "reads them, print each path written and what to run next. Needs root "
                    "for / (sudo), or --prefix for a staging directory.")
    what = p.add_subparsers(dest="what", required=True, metavar="WHAT")
    udev = what.add_parser("udev", help="the rules that let a user open the boards")
    udev.add_argument("--access", choices=tuple(UDEV_ACCESS), default="uaccess",
                      help="who gets the boards: the user at the seat (uaccess, default, "
                           "desktops with systemd-logind) or the plugdev group (headless)")
    systemd = what.add_parser("systemd", help="micam-daemon.service and micam-web.service")
    systemd.add_argument("--micam", type=Path, default=None, metavar="PATH",
                         help="the micam executable the units run (default: this one, "
                              f"{_this_micam()})")
    for command in (udev, systemd):
        command.add_argument("--prefix", type=Path, default=Path("/"), metavar="DIR",
                             help="write under DIR instead of / (a package's staging root)")
        command.add_argument("--dry-run", action="store_true",
                             help="print what would be written, write nothing")
        command.add_argument("--force", action="store_true",
                             help="replace a file that exists with other content")
        command.set_defaults(run=run)


def _this_micam() -> Path:
    """The `micam` console script of this installation (beside the interpreter)."""
    beside = Path(sys.executable).parent / "micam"
    found = shutil.which("micam")
    return beside if beside.exists() or found is None else Path(found)


def planned(args: argparse.Namespace) -> list[tuple[Path, str]]:
    """(path, content) of every file the command writes."""
    if args.what == "udev":
        names = (UDEV_FLAG, UDEV_ACCESS[args.access])
        return [(args.prefix / UDEV_DIR / n, shipped("udev", n)) for n in names]
    micam = str((args.micam or _this_micam()).absolute())
    return [(args.prefix / SYSTEMD_DIR / n, shipped("systemd", n).replace(MICAM_TOKEN, micam))
            for n in UNITS]


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.session import write_atomic

    plan = planned(args)
    for path, content in plan:
        if path.exists() and path.read_text() != content and not args.force:
            raise UserError(f"{path} exists with other content; pass --force to replace it")
    for path, content in plan:
        if args.dry_run:  # what would be written, in full: the rules or units to review
            print(f"would write {path}:")
            print(textwrap.indent(content.rstrip("\n"), "    "))
            continue
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            data = content.encode()
            write_atomic(path, lambda fh: fh.write(data), replace=True)  # called at once
        except PermissionError:
            raise UserError(f"cannot write {path}: run it as root (sudo micam install "
                            f"{args.what}) or pass --prefix DIR") from None
        print(f"wrote {path}")
    if args.what == "udev":
        print("then: udevadm control --reload-rules && udevadm trigger --subsystem-match=usb,"
              " and replug the boards" + (" (and add the user to plugdev)"
                                          if args.access == "plugdev" else ""))
    else:
        print("then: systemctl daemon-reload && systemctl enable --now micam-daemon "
              "(and micam-web for the operator's page)")
    return 0
