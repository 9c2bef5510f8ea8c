"""`micam install udev|systemd`: the udev rules and systemd units shipped in the package,
written where udev and systemd read them, with what was written printed.

`systemd` also writes what the units need to start: a sysusers.d file declaring the daemon's
`micam` user and group (`systemd-sysusers` creates them), and /etc/micam/daemon.toml from a
template when it is missing (an existing configuration is never touched). The units run the
micam of an installation outside the home directories: the daemon's user and the page's
dynamic user (ProtectHome=yes) cannot read a virtualenv under /home.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

from acquisition.contracts.errors import UserError

from ..data import shipped

UDEV_DIR = Path("etc/udev/rules.d")
SYSTEMD_DIR = Path("etc/systemd/system")
UDEV_FLAG = "60-micam-daq.rules"
UDEV_ACCESS = {"uaccess": "61-micam-daq-uaccess.rules", "plugdev": "61-micam-daq-plugdev.rules"}
UNITS = ("micam-daemon.service", "micam-web.service")
SYSUSERS = Path("etc/sysusers.d/micam.conf")
DAEMON_CONFIG = Path("etc/micam/daemon.toml")
"""The configuration micam-daemon.service reads (its ExecStart's --config)."""
DAEMON_TEMPLATES = ("generic", "paper", "audio", "uma16")
HOMES = (Path("/home"), Path("/root"), Path("/run/user"))
"""Directories the services cannot read (ProtectHome=yes; a home's mode keeps others out)."""
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
    where = systemd.add_mutually_exclusive_group()
    where.add_argument("--micam", type=Path, default=None, metavar="PATH",
                       help="the micam executable the units run (default: this one, else "
                            "the one on PATH)")
    where.add_argument("--venv", type=Path, default=None, metavar="DIR",
                       help="the virtualenv micam is installed in: the units run DIR/bin/micam")
    systemd.add_argument("--config-template", choices=DAEMON_TEMPLATES, default="generic",
                         help="the template /etc/micam/daemon.toml is written from when it is "
                              "missing (default: generic; `micam config template --help`)")
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


@dataclass(frozen=True)
class Planned:
    """A file the command writes; `keep` when an existing one is left as it is (a
    configuration the lab has edited), else it is replaced with --force only."""

    path: Path
    content: str
    keep: bool = False


def units_micam(args: argparse.Namespace) -> Path:
    """The micam the units run: --micam, --venv's, else this one; refused under a home."""
    micam = (args.micam or (args.venv / "bin/micam" if args.venv else _this_micam())).absolute()
    home = next((h for h in HOMES if micam.is_relative_to(h)), None)
    if home is not None:
        raise UserError(
            f"the units would run {micam}, under {home}, which the services cannot read "
            "(user micam; the page's dynamic user has ProtectHome=yes): install micam outside "
            "the home directories, e.g. sudo python3 -m venv /opt/micam && sudo /opt/micam/bin"
            "/pip install micam-VERSION-py3-none-any.whl, then pass --venv /opt/micam")
    return micam


def planned(args: argparse.Namespace) -> list[Planned]:
    """Every file the command writes."""
    if args.what == "udev":
        names = (UDEV_FLAG, UDEV_ACCESS[args.access])
        return [Planned(args.prefix / UDEV_DIR / n, shipped("udev", n)) for n in names]
    from micam.templates import template

    micam = str(units_micam(args))
    return [*(Planned(args.prefix / SYSTEMD_DIR / n,
                      shipped("systemd", n).replace(MICAM_TOKEN, micam)) for n in UNITS),
            Planned(args.prefix / SYSUSERS, shipped("systemd", SYSUSERS.name)),
            Planned(args.prefix / DAEMON_CONFIG, template(args.config_template), keep=True)]


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.session import write_atomic

    plan = planned(args)
    for file in plan:
        if (not file.keep and file.path.exists() and file.path.read_text() != file.content
                and not args.force):
            raise UserError(f"{file.path} exists with other content; pass --force to replace "
                            "it")
    for file in plan:
        if file.keep and file.path.exists():
            print(f"kept {file.path} (an existing configuration is never overwritten)")
            continue
        if args.dry_run:  # what would be written, in full: the rules or units to review
            print(f"would write {file.path}:")
            print(textwrap.indent(file.content.rstrip("\n"), "    "))
            continue
        try:
            file.path.parent.mkdir(parents=True, exist_ok=True)
            data = file.content.encode()
            write_atomic(file.path, lambda fh: fh.write(data), replace=True)  # called at once
            os.chmod(file.path, 0o644)  # the services' users read them whatever the umask
        except PermissionError:
            raise UserError(f"cannot write {file.path}: run it as root (sudo micam install "
                            f"{args.what}) or pass --prefix DIR") from None
        print(f"wrote {file.path}")
    print(next_steps(args))
    return 0


def next_steps(args: argparse.Namespace) -> str:
    """What to run after the files are in place, with the paths they have on the target."""
    if args.what == "udev":
        return ("then: udevadm control --reload-rules && udevadm trigger --subsystem-match=usb,"
                " and replug the boards" + (" (and add the user to plugdev)"
                                            if args.access == "plugdev" else ""))
    config = Path("/") / DAEMON_CONFIG
    return "\n".join([
        f"then: systemd-sysusers /{SYSUSERS}   # creates the user and group micam (or: "
        "useradd --system --user-group --home-dir /var/lib/micam --shell /usr/sbin/nologin "
        "micam)",
        f"      edit {config} (what its comments point out), then micam config check {config}",
        "      systemctl daemon-reload && systemctl enable --now micam-daemon (and micam-web "
        "for the operator's page)"])
