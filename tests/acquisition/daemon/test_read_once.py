"""A user's file is read once: what is checked is what runs, even from a pipe.

`micam daemon --config <(...)` hands the daemon a pipe (/dev/fd/N), which can be read only
once; a second opening of it reads nothing. So a check that read the file and a loader that
read it again passed a `0.0.0.0` bind (the loader saw an empty file: the defaults), and the
daemon ran on the default session root. The tests hand over real pipes, and a file of more than
1 MiB, which is refused rather than read to its end (`--config /dev/zero` would never end).
A camera's intrinsics file (`micam calibrate --intrinsics`, an import's) is read once too.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.contracts.bounded_files import MAX_TOML_BYTES
from acquisition.intrinsics_file import read_intrinsics
from acquisition.daemon.config import ConfigError
from micam.cli import main
from micam.hardware import load_daemon_config

from .helpers import DaemonProcess, write_toml

EXPOSED = '[sockets]\ncontrol = "tcp://0.0.0.0:5560"\nevents = "tcp://0.0.0.0:5561"\n'


@contextmanager
def pipe_holding(text: str) -> Iterator[Path]:
    """A pipe holding `text` (then its end), as `<(...)` gives: its path /dev/fd/N."""
    read, write = os.pipe()
    try:
        os.write(write, text.encode())  # a configuration fits a pipe's 64 KiB at once
        os.close(write)
        yield Path(f"/dev/fd/{read}")
    finally:
        os.close(read)


@pytest.mark.parametrize("command", [["daemon", "--check", "--config"], ["config", "check"]])
def test_a_check_of_a_pipe_checks_what_it_holds(command: list[str],
                                                capsys: pytest.CaptureFixture[str]) -> None:
    with pipe_holding(EXPOSED) as path:
        assert main([*command, str(path)]) == 2
    err = capsys.readouterr().err
    assert "tcp://0.0.0.0:5560" in err and "CURVE" in err and err.count("\n") == 1


@pytest.mark.slow
def test_a_daemon_runs_on_the_configuration_of_a_pipe(tmp_path: Path) -> None:
    text = write_toml(tmp_path / "daemon.toml", tmp_path).read_text()
    defaults = {"HOME": str(tmp_path / "home"), "MICAM_RUNTIME_DIR": str(tmp_path / "run")}
    with pipe_holding(text) as path:  # (the defaults kept inside tmp_path, should they win)
        process = DaemonProcess(path, tmp_path, env=defaults, pass_fds=(int(path.name),))
    try:
        ready = process.wait_message("READY=1")
    finally:
        process.kill()
    assert f"sessions in {tmp_path}/sessions" in ready


def test_a_config_above_the_limit_is_refused(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "daemon.toml"
    padding = "# padding\n" * (MAX_TOML_BYTES // 10)
    path.write_text(f'session_root = "{tmp_path}"\n{padding}')
    with pytest.raises(ConfigError, match=f"config file {path} is larger than 1 MiB"):
        load_daemon_config(path)
    assert main(["daemon", "--check", "--config", "/dev/zero"]) == 2  # never read to its end
    assert "/dev/zero is larger than 1 MiB" in capsys.readouterr().err


def test_the_environment_still_overrides_the_file(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MICAM_DAEMON_SOCKETS__EVENTS", "ipc:///run/other-events")
    with pipe_holding('session_root = "/data/s"\n[sockets]\nevents = "ipc:///run/e"\n'
                      'control = "ipc:///run/c"\n') as path:
        config = load_daemon_config(path)
    assert config.session_root == Path("/data/s") and config.sockets.control == "ipc:///run/c"
    assert config.sockets.events == "ipc:///run/other-events"


def test_an_intrinsics_file_from_a_pipe_is_read(tmp_path: Path) -> None:
    K = np.array([[800.0, 0.0, 320.0], [0.0, 800.0, 240.0], [0.0, 0.0, 1.0]])
    written = cv2.FileStorage(str(tmp_path / "cam0.xml"), cv2.FILE_STORAGE_WRITE)
    written.write("camera_matrix", K)
    written.write("distortion_coefficients", np.array([[0.1, -0.05, 0.0, 0.0, 0.01]]))
    written.release()
    with pipe_holding((tmp_path / "cam0.xml").read_text()) as path:
        known = read_intrinsics(path, "cam0", None, use="fixed")
    assert np.array_equal(known.camera_matrix, K)
