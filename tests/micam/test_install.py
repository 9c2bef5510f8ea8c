"""`micam install udev|systemd` writes the files shipped in the package, and says so."""

from __future__ import annotations

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


@pytest.mark.parametrize("what", ["systemd", "udev"])
def test_dry_run_writes_nothing_and_shows_what_it_would(
        what: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["install", what, "--prefix", str(tmp_path), "--dry-run"]) == 0
    assert not any(tmp_path.iterdir())
    out = capsys.readouterr().out
    assert "would write" in out
    marker = 'ATTRS{idVendor}=="0867"' if what == "udev" else "ExecStart="
    assert marker in out, out  # the rules and units themselves, not only their paths


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
