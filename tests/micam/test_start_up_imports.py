"""What a daemon loads at start-up: never the simulator on real hardware, never scipy.signal
(most of its start-up time, needed only when the first burst is made). Each check runs in a
fresh interpreter, whose sys.modules is what that start-up imported."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from micam.templates import template

SIM_MODULES = "sorted(m for m in sys.modules if m == 'sim' or m.startswith('sim.'))"


def _run(code: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MICAM_DAEMON_SESSION_ROOT": str(tmp_path / "sessions"),
           "XDG_RUNTIME_DIR": str(tmp_path)}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, env=env, cwd=tmp_path)


@pytest.mark.slow
def test_the_daemon_on_real_hardware_loads_no_simulator(tmp_path: Path) -> None:
    """`micam daemon` with the generic template's boards (not on this bus: it ends with "cannot
    open the hardware" after reading its configuration); the same check of a configuration
    without [hardware] does load the simulator, for its [simulation] section."""
    real = tmp_path / "real.toml"
    real.write_text(template("generic"))
    simulated = tmp_path / "simulated.toml"
    simulated.write_text("[simulation]\narray = 'scatter48'\n")
    code = ("import sys; from micam.cli import main; rc = main(['daemon', '--config', {!r}]); "
            f"print(rc, {SIM_MODULES})")
    on_hardware = _run(code.format(str(real)), tmp_path)
    assert "cannot open the hardware" in on_hardware.stderr
    assert on_hardware.stdout.strip() == "2 []", on_hardware.stdout
    checked = _run(code.format(str(simulated)).replace("'daemon',", "'daemon', '--check',"),
                   tmp_path)
    assert checked.stdout.startswith("configuration OK: simulated world")
    assert "'sim.capture'" in checked.stdout


@pytest.mark.slow
def test_the_daemon_service_imports_no_scipy_signal(tmp_path: Path) -> None:
    done = _run("import sys, acquisition.daemon.service; "
                "print(sorted(m for m in sys.modules if m.startswith('scipy.signal')))", tmp_path)
    assert done.stdout.strip() == "[]", done.stdout + done.stderr
