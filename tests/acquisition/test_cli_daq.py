"""`micam daq` and `micam simulate --backend usb-emulated`: the real USB driver, emulated boards."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from micam.cli import main
from acquisition.contracts.session import SessionReader


def test_daq_list_emulated_shows_every_board(capsys: pytest.CaptureFixture) -> None:
    assert main(["daq", "list", "--emulate"]) == 0
    out = capsys.readouterr().out
    assert out.count("DT9836-12-2") == 3 and out.count("DT9816-A") == 7
    assert "36001" in out and "16099" in out and "running" in out


@pytest.mark.slow
def test_daq_selftest_emulated_passes(capsys: pytest.CaptureFixture) -> None:
    assert main(["daq", "selftest", "--emulate", "--seconds", "0.05"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.strip()]
    assert len(lines) == 10 and all(ln.endswith(": ok") for ln in lines)


def test_selftest_refuses_a_nonpositive_length(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["daq", "selftest", "--emulate", "--seconds", "0"])
    assert exited.value.code == 2
    assert "argument --seconds: 0 is not a number above 0" in capsys.readouterr().err


@pytest.mark.slow
def test_usb_emulated_capture_records_what_the_plain_simulation_records(tmp_path: Path) -> None:
    common = ["--array", "scatter48", "--poses", "1", "--mls-order", "9", "--quiet"]
    assert main(["simulate", "--out", str(tmp_path / "usb"), "--backend", "usb-emulated",
                 *common]) == 0
    assert main(["simulate", "--out", str(tmp_path / "sim"), *common]) == 0
    usb, plain = SessionReader(tmp_path / "usb"), SessionReader(tmp_path / "sim")
    assert usb.status == plain.status == "complete"
    for step, name in [("reference/3", "speaker_3.wav"), ("pose/0000", "speaker_5.wav")]:
        assert np.array_equal(usb.read_recording(step, name)[0],
                              plain.read_recording(step, name)[0])
