"""`micam simulate` from the command line: a session on disk, clear errors, kill and resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from micam.cli import main
from acquisition.contracts.session import SessionReader, journal_records

QUICK = ["--array", "scatter48", "--poses", "2", "--mls-order", "9", "--quiet"]


@pytest.mark.slow
def test_simulate_writes_session_and_truth(tmp_path: Path) -> None:
    out = tmp_path / "s"
    assert main(["simulate", "--out", str(out), *QUICK]) == 0
    assert SessionReader(out).status == "complete"
    truth = json.loads((out / "truth.json").read_text())
    assert {"microphones", "speed_of_sound_m_s", "cameras", "poses"} <= set(truth)
    assert truth["microphones"][0].keys() >= {"id", "position_m"}
    assert len(truth["poses"]) == 2


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--array", "cube"], "unknown array 'cube'"),
        (["--poses", "0"], "poses"),
        (["--distance", "1.0", "0.5"], "distance range"),
        (["--noise", "-1"], "noise"),
        (["--temperature", "300"], "temperature"),
        (["--mls-order", "9", "--mls-periods", "2"], "fold the room onto the direct sound"),
    ],
)
def test_bad_options_are_explained(tmp_path: Path, capsys: pytest.CaptureFixture,
                                   args: list[str], message: str) -> None:
    status: int | str | None
    try:  # a value out of its option's range is argparse's usage error, the rest micam's
        status = main(["simulate", "--out", str(tmp_path / "s"), "--quiet", *args])
    except SystemExit as exc:
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err
    assert "error:" in err and message in err and "Traceback" not in err
    assert not (tmp_path / "s").exists()


def test_existing_session_is_never_overwritten(tmp_path: Path,
                                               capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "s"
    assert main(["simulate", "--out", str(out), *QUICK]) == 0
    before = (out / "journal.jsonl").read_bytes()
    assert main(["simulate", "--out", str(out), *QUICK]) == 2
    err = capsys.readouterr().err
    assert "micam: error:" in err and "already holds a session" in err
    assert f"micam simulate --resume --out {out}" in err  # the command-line way, not the API
    assert (out / "journal.jsonl").read_bytes() == before


def test_resume_needs_a_simulated_session(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert main(["simulate", "--resume", "--out", str(tmp_path)]) == 2
    assert "truth.json is missing" in capsys.readouterr().err


@pytest.mark.slow
def test_sigkill_during_capture_then_resume(tmp_path: Path) -> None:
    """A real kill -9 in the middle of a burst; the resumed session is complete and intact."""
    out = tmp_path / "s"
    cmd = [sys.executable, "-m", "micam.cli", "simulate", "--out", str(out),
           "--array", "scatter48", "--poses", "3", "--mls-order", "12", "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    journal = out / "journal.jsonl"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # wait until the first pose has begun
        if journal.exists() and b'"pose/0000"' in journal.read_bytes():
            break
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert SessionReader(out).status == "interrupted"
    assert main(["simulate", "--resume", "--out", str(out), "--quiet"]) == 0
    reader = SessionReader(out)
    assert reader.status == "complete" and reader.verify() == []
    kinds = [r.kind for r in journal_records(journal)]
    assert kinds.count("session_resume") == 1
    assert len(reader.steps()) == 6 + 1 + 3
