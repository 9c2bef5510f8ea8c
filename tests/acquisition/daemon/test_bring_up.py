"""Bringing a lab up a piece at a time (`only_boards`, `micam daemon --boards` /
`--cameras-only`): the daemon runs with the cameras alone or some of its boards, the previews
work, and a capture or live mode, which record every board, is refused with a message saying
which boards are missing and how to get them back."""

from __future__ import annotations

import base64
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.contracts.errors import UserError
from acquisition.contracts.protocol import PreviewEvent
from acquisition.daemon.client import DaemonClient, DaemonError
from micam.cli import build_parser
from micam.hardware import open_hardware

from .helpers import DaemonProcess, ThreadDaemon, small_config, write_toml


def _world_serials(tmp_path: Path) -> list[str]:
    with open_hardware(small_config(tmp_path)) as hardware:
        return [b.serial for b in hardware.config.boards]


def _refused(client: DaemonClient, command: str, **args: object) -> str:
    with pytest.raises(DaemonError) as refused:
        client.request(command, **args)
    return str(refused.value)


def test_the_cameras_alone_give_previews_and_refuse_a_capture(tmp_path: Path) -> None:
    with ThreadDaemon(small_config(tmp_path, only_boards=())) as daemon:
        assert daemon.hardware.group is None  # no board opened
        with daemon.client() as client:
            stream = client.subscribe(previews=True)
            try:
                time.sleep(0.3)  # the subscription reaches the publisher
                client.request("previews", seconds=1.0)
                deadline, shown = time.monotonic() + 5.0, None
                while shown is None and time.monotonic() < deadline:
                    event = stream.next(0.5)
                    shown = event if isinstance(event, PreviewEvent) else None
            finally:
                stream.close()
            assert shown is not None and shown.camera == "cam0"
            image = cv2.imdecode(np.frombuffer(base64.b64decode(shown.jpeg_b64), np.uint8),
                                 cv2.IMREAD_GRAYSCALE)
            assert image is not None
            assert image.shape[1] == shown.width and image.std() > 10  # the rig, not a blank
            for command, what in (("session.start", "a capture"), ("live.start", "live mode")):
                message = _refused(client, command)
                assert what in message and "cameras alone" in message and "--boards" in message
            assert client.status().state == "idle" and client.status().session is None


def test_one_board_alone_is_open_and_the_capture_names_the_others(tmp_path: Path) -> None:
    serials = _world_serials(tmp_path / "probe")
    assert len(serials) >= 2
    with ThreadDaemon(small_config(tmp_path, only_boards=(serials[1],))) as daemon:
        assert daemon.hardware.group is not None
        assert [b.identity.serial for b in daemon.hardware.group.boards] == [serials[1]]
        with daemon.client() as client:
            assert len(client.request("describe")["columns"]) > 0
            message = _refused(client, "session.start", poses=1)
    left_out = [s for s in serials if s != serials[1]]
    assert f"with board {serials[1]} only" in message
    assert f"without {', '.join(left_out)}" in message


def test_a_board_the_configuration_has_not_is_refused_naming_those_it_has(
        tmp_path: Path) -> None:
    serials = _world_serials(tmp_path / "probe")
    with pytest.raises(UserError, match=f"no board NOPE .*{serials[0]}"):
        open_hardware(small_config(tmp_path, only_boards=("NOPE",)))


def test_boards_and_cameras_only_options() -> None:
    parser = build_parser()
    assert parser.parse_args(["daemon", "--boards", "S1, S2"]).boards == ("S1", "S2")
    assert parser.parse_args(["daemon", "--cameras-only"]).boards == ()
    assert parser.parse_args(["daemon"]).boards is None
    with pytest.raises(SystemExit):
        parser.parse_args(["daemon", "--boards", ","])


@pytest.mark.slow  # a daemon process: about 2 s
def test_micam_daemon_cameras_only_starts_and_refuses_a_capture(tmp_path: Path) -> None:
    config = write_toml(tmp_path / "daemon.toml", tmp_path)
    daemon = DaemonProcess(config, tmp_path, script=[sys.executable, "-m", "micam.cli",
                                                     "daemon", "--cameras-only", "--config"])
    try:
        daemon.wait_message("READY=1")
        with daemon.client() as client:
            assert "cameras alone" in _refused(client, "session.start")
        daemon.proc.terminate()
        assert daemon.wait_exit() == 0
    finally:
        if daemon.proc.poll() is None:
            daemon.kill()


def test_config_check_names_what_comes_up_and_refuses_an_unknown_board(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from micam.cli import EXIT_USAGE, main
    from micam.templates import template

    config = tmp_path / "daemon.toml"
    for only, expected in (('["36002"]', "boards 36002 alone"), ("[]", "the cameras alone")):
        config.write_text(f"only_boards = {only}\n" + template("paper"))
        assert main(["daemon", "--check", "--config", str(config)]) == 0
        assert expected in capsys.readouterr().out
    config.write_text('only_boards = ["XX"]\n' + template("paper"))
    assert main(["daemon", "--check", "--config", str(config)]) == EXIT_USAGE
    assert "no board XX" in capsys.readouterr().err
