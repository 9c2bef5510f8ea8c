"""The udev rules cover the loader and running ids of every board family the driver knows."""

from __future__ import annotations

import re
from pathlib import Path

from daq.usb import FAMILIES

UDEV = Path(__file__).resolve().parents[2] / "udev"


def test_flag_rules_cover_every_loader_and_running_id() -> None:
    text = (UDEV / "60-micam-daq.rules").read_text()
    flagged = set(re.findall(r'ATTRS\{idVendor\}=="0867", ATTRS\{idProduct\}=="([0-9a-f]{4})",'
                             r' ENV\{ID_MICAM_DAQ\}="1"', text))
    wanted = {f"{pid:04x}" for f in FAMILIES for pid in (f.loader_pid, f.running_pid)}
    assert flagged == wanted


def test_access_rules_use_the_flag() -> None:
    assert 'ENV{ID_MICAM_DAQ}=="1", TAG+="uaccess"' in (
        UDEV / "61-micam-daq-uaccess.rules").read_text()
    assert 'ENV{ID_MICAM_DAQ}=="1", MODE="0660", GROUP="plugdev"' in (
        UDEV / "61-micam-daq-plugdev.rules").read_text()
