"""`micam install udev|systemd` writes the files shipped in the package, and says so."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from micam.cli import EXIT_USAGE, main
from micam.commands.install import MICAM_TOKEN


def test_udev_writes_the_flag_and_the_chosen_access_rules(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["install", "udev", "--prefix", str(tmp_path), "--access", "plugdev"]) == 0
    rules = tmp_path / "etc/udev/rules.d"
    assert sorted(p.name for p in rules.iterdir()) == ["60-micam-daq.rules",
                                                         "61-micam-daq-plugdev.rules"]
    assert 'GROUP="plugdev"' in (rules / "61-micam-daq-plugdev.rules").read_text()
    out = capsys.readouterr().out
    assert f"wrote {rules / '60-micam-daq.rules'}" in out and "udevadm" in out


def test_systemd_units_name_the_installed_micam(tmp_path: Path) -> None:
    micam = tmp_path / "venv/bin/micam"
    assert main(["install", "systemd", "--prefix", str(tmp_path), "--micam", str(micam)]) == 0
    units = tmp_path / "etc/systemd/system"
    for name in ("micam-daemon.service", "micam-web.service"):
        text = (units / name).read_text()
        assert f"ExecStart={micam} " in text and MICAM_TOKEN not in text
        assert "/opt/micam" not in text


@pytest.mark.parametrize("what", [["systemd", "--micam", "/opt/micam/bin/micam"], ["udev"]])
def test_dry_run_writes_nothing_and_shows_what_it_would(
        what: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["install", *what, "--prefix", str(tmp_path), "--dry-run"]) == 0
    assert not any(tmp_path.iterdir())
    out = capsys.readouterr().out
    assert "would write" in out
    # the rules, units, user and configuration themselves, not only their paths
    markers = (['ATTRS{idVendor}=="0867"'] if what[0] == "udev" else
               ["ExecStart=/opt/micam/bin/micam daemon", 'u micam - "micam', "[hardware.capture]",
                "systemd-sysusers /etc/sysusers.d/micam.conf"])
    assert all(m in out for m in markers), out


def test_systemd_declares_the_user_and_writes_the_config_the_units_name(tmp_path: Path) -> None:
    """What micam-daemon.service needs to start: its User= declared for systemd-sysusers, its
    --config written from a template that validates; the units run the venv's micam."""
    from micam.hardware import load_daemon_config

    assert main(["install", "systemd", "--prefix", str(tmp_path), "--venv", "/opt/micam",
                 "--config-template", "paper"]) == 0
    daemon = (tmp_path / "etc/systemd/system/micam-daemon.service").read_text()
    settings = dict(line.split("=", 1) for line in daemon.splitlines()
                    if "=" in line and not line.startswith("#"))
    exec_start = settings["ExecStart"].split()
    assert exec_start[:2] == ["/opt/micam/bin/micam", "daemon"]
    config = tmp_path / exec_start[exec_start.index("--config") + 1].lstrip("/")
    hardware = load_daemon_config(config).hardware  # the template, validated
    assert hardware is not None and len(hardware.capture.boards) == 10  # paper's, asked for
    sysusers = (tmp_path / "etc/sysusers.d/micam.conf").read_text().splitlines()
    (user,) = [line.split() for line in sysusers if line.startswith("u ")]
    assert user[1] == settings["User"] == settings["Group"]
    web = (tmp_path / "etc/systemd/system/micam-web.service").read_text()
    assert f"SupplementaryGroups={user[1]}" in web


def test_an_existing_daemon_config_is_never_overwritten(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "etc/micam/daemon.toml"
    config.parent.mkdir(parents=True)
    config.write_text("# this lab's\n")
    for extra in ([], ["--force"]):
        assert main(["install", "systemd", "--prefix", str(tmp_path), "--micam",
                     "/opt/micam/bin/micam", *extra]) == 0
        assert config.read_text() == "# this lab's\n"
        assert f"kept {config}" in capsys.readouterr().out


@pytest.mark.parametrize("micam", ["--venv=/home/ana/.venv", "--micam=/root/venv/bin/micam"])
def test_a_micam_under_a_home_the_services_cannot_read_is_refused(
        micam: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["install", "systemd", "--prefix", str(tmp_path), micam]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "ProtectHome" in err and "--venv /opt/micam" in err and not any(tmp_path.iterdir())


def test_a_changed_file_is_kept_without_force(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    rules = tmp_path / "etc/udev/rules.d/60-micam-daq.rules"
    rules.parent.mkdir(parents=True)
    rules.write_text("# local edit\n")
    assert main(["install", "udev", "--prefix", str(tmp_path)]) == EXIT_USAGE
    assert "--force" in capsys.readouterr().err and rules.read_text() == "# local edit\n"
    assert main(["install", "udev", "--prefix", str(tmp_path), "--force"]) == 0
    assert "ID_MICAM_DAQ" in rules.read_text()


def test_again_with_the_same_content_is_fine(tmp_path: Path) -> None:
    assert main(["install", "udev", "--prefix", str(tmp_path)]) == 0
    assert main(["install", "udev", "--prefix", str(tmp_path)]) == 0


REPO = Path(__file__).resolve().parents[2]
BUILT_FROM = ("pyproject.toml", "setup.py", "README.md", "udev", "kernel", "daq", "sim",
              "acquisition", "calibration", "imaging", "micam")
"""What the wheel is built from, copied (pip builds in the source tree, which a test leaves as
it was)."""


@pytest.mark.slow
def test_the_built_wheel_ships_the_udev_rules_and_installs_them(tmp_path: Path) -> None:
    """`pip wheel` maps udev/ into the package; `micam install udev` run from the unpacked
    wheel (a purelib wheel installs as its unpacked files) writes the rules of udev/, and
    `micam install systemd` the units, the sysusers file and the daemon's configuration."""
    source = tmp_path / "source"
    for name in BUILT_FROM:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, source / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            source.mkdir(exist_ok=True)
            shutil.copy2(REPO / name, source / name)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                            str(tmp_path / "dist"), str(source)],
                           capture_output=True, text=True, timeout=240)
    assert built.returncode == 0, built.stderr
    (wheel,) = (tmp_path / "dist").glob("micam-*.whl")
    shipped = {n for n in zipfile.ZipFile(wheel).namelist() if n.startswith("micam/data/udev/")}
    rules = sorted(p.name for p in (REPO / "udev").glob("*.rules"))
    assert shipped == {f"micam/data/udev/{n}" for n in [*rules, "README.md"]}
    units = {n for n in zipfile.ZipFile(wheel).namelist() if n.startswith("micam/data/systemd/")}
    assert units == {f"micam/data/systemd/{p.name}"
                     for p in (REPO / "micam/data/systemd").iterdir()}  # the sysusers file too
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    root = str(tmp_path / "root")
    code = ("import sys, micam; from micam.cli import main; "
            f"assert micam.__file__.startswith({str(site)!r}), micam.__file__; "
            f"assert main(['install', 'systemd', '--prefix', {root!r}, '--venv', '/opt/m']) == 0;"
            f"sys.exit(main(['install', 'udev', '--prefix', {root!r}]))")
    installed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               timeout=120, cwd=tmp_path,
                               env={**os.environ, "PYTHONPATH": str(site)})
    assert installed.returncode == 0, installed.stderr
    written = tmp_path / "root/etc/udev/rules.d"
    for name in ("60-micam-daq.rules", "61-micam-daq-uaccess.rules"):
        assert (written / name).read_text() == (REPO / "udev" / name).read_text()
    etc = tmp_path / "root/etc"  # the units, the user and the configuration, from the wheel
    assert "ExecStart=/opt/m/bin/micam daemon" in (
        etc / "systemd/system/micam-daemon.service").read_text()
    assert (etc / "sysusers.d/micam.conf").read_text() == (
        REPO / "micam/data/systemd/micam.conf").read_text()
    assert "[hardware.capture]" in (etc / "micam/daemon.toml").read_text()
