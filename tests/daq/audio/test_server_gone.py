"""The audio server going away mid-capture (jackd killed): the capture is abandoned with the
device named, nothing recorded is lost, and once the server is back a new daemon offers the
session, resumes it and captures the lost step again. PortAudio cannot reconnect to a new JACK server in the process that
knew the old one (it hangs stopping a stream whose server died): a daemon is restarted, as
systemd restarts it (docs/hardware.md)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
from pathlib import Path

import pytest

from acquisition.contracts.session import SessionReader

from ...acquisition.daemon.helpers import capture
from .jack_helpers import JackServer, require_audio_stack
from .test_daemon_audio import audio_daemon

pytestmark = pytest.mark.slow  # every test here: a JACK server and the world as its client

WORLD = {"array": "scatter15", "poses": 1, "mls_order": 10, "seed": 3, "backend": "audio"}


def _stop(daemon) -> None:  # noqa: ANN001
    """SIGTERM, then SIGKILL: a daemon whose server died may hang in PortAudio at exit."""
    daemon.proc.send_signal(signal.SIGTERM)
    try:
        daemon.proc.wait(15)
    except subprocess.TimeoutExpired:
        daemon.proc.kill()
    daemon.wait_exit()


def test_a_vanished_server_leaves_the_session_resumable(tmp_path: Path) -> None:
    require_audio_stack()
    name = f"micam-gone-{os.getpid()}"
    server = JackServer(name, tmp_path)
    root = tmp_path / "daemon"
    root.mkdir()
    daemon = audio_daemon(root, WORLD, env=server.env)
    try:
        with daemon.client(timeout_s=30.0) as client:
            path = Path(client.request("session.start")["session"]["path"])
            assert capture(client).last_capture.outcome == "complete"  # type: ignore[union-attr]
            number = client.request("capture")["number"]  # reference/1, while the server dies
            server.kill()
            status = client.wait_until(lambda s: s.last_capture is not None
                                       and s.last_capture.number >= number, 60.0)
        last = status.last_capture
        assert last is not None and last.outcome == "abandoned"
        assert "DeviceDisconnectedError: audio interface world" in last.reason
        assert re.search(r"the JACK server shut down|its audio server went away", last.reason)
    finally:
        _stop(daemon)
    reader = SessionReader(path)
    assert reader.status == "interrupted" and reader.verify() == []
    assert set(reader.steps()) == {"reference/0"}

    server = JackServer(name, tmp_path)
    daemon = audio_daemon(root, WORLD, env=server.env)
    try:
        with daemon.client(timeout_s=30.0) as client:
            offered = client.wait_until(lambda s: s.resumable is not None, 30.0)
            assert offered.resumable == path.name
            client.request("session.start", resume="last")
            assert capture(client).last_capture.outcome == "complete"  # type: ignore[union-attr]
    finally:
        _stop(daemon)
        server.stop()
    reader = SessionReader(path)  # the step lost to the server is captured again, whole
    assert set(reader.steps()) == {"reference/0", "reference/1"} and reader.verify() == []
    assert reader.steps()["reference/1"].attempt == 2
