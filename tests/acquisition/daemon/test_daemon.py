"""The daemon serving in a thread on the small simulated world: commands, states, checks.

Component tests: the real daemon code and sockets (ipc), simulated boards and cameras.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from acquisition.daemon.client import DaemonClient, DaemonError
from acquisition.daemon.config import CurveConfig, HandsFreeConfig, QualityConfig, SocketsConfig
from acquisition.contracts.keys import make_keys
from acquisition.contracts.protocol import RedoRequest
from acquisition.daemon.translog import read_transitions
from acquisition.contracts.session import (SessionReader, SessionStop, SessionWriter,
                                           journal_records)
from sim.cameras import SimulatedCamera
from sim.capture import SimulationOptions, build_simulated_capture

from .helpers import ThreadDaemon, capture, small_config, wait_state

REFERENCE_STEPS = 7  # six speakers and the reference-microphone image


@pytest.fixture
def client(daemon: ThreadDaemon) -> Iterator[DaemonClient]:
    with daemon.client() as c:
        yield c


def _refused(client: DaemonClient, command: str, code: str, **args) -> str:
    with pytest.raises(DaemonError) as caught:
        client.request(command, **args)
    assert caught.value.code == code, caught.value
    return str(caught.value)


def test_bad_input_gets_clear_errors_and_the_daemon_keeps_serving(client: DaemonClient) -> None:
    cases = [
        ([b"\x00garbage"], "bad_request", "not UTF-8 JSON"),
        ([b'{"v": 2, "command": "status"}', b"extra"], "bad_request", "2 frames"),
        ([b'{"v": 2, "command": "status", "pad": "' + b"x" * 100_000 + b'"}'], "too_large",
         "65536"),
        ([b'{"v": 2, "command": "selfdestruct"}'], "unknown_command", "selfdestruct"),
        ([b'{"v": 7, "command": "status"}'], "unsupported_version", "version 7"),
    ]
    for frames, code, words in cases:
        reply = client.exchange(frames)
        assert not reply.ok and reply.error is not None
        assert reply.error.code == code and words in reply.error.message
    assert "micam session start" in _refused(client, "capture", "wrong_state")
    assert "no session is open" in _refused(client, "session.abort", "wrong_state")
    assert client.request("ping")["pong"] is True
    with pytest.raises(DaemonError, match=r"did not finish within 0\.05 s"):
        client.wait_until(lambda s: s.state == "capturing", 0.05, interval_s=0.01)


@pytest.mark.slow
def test_session_with_pause_refusals_stop_and_journal(daemon: ThreadDaemon,
                                                      client: DaemonClient) -> None:
    started = client.request("session.start", poses=2)["session"]
    wait_state(client, "references")
    assert "session.start while references" in _refused(client, "session.start", "wrong_state")
    client.request("session.pause")  # at the very first step
    assert "micam session resume" in _refused(client, "capture", "wrong_state")
    assert "cannot stop" in _refused(client, "session.stop", "wrong_state")
    client.request("session.resume")
    for _ in range(REFERENCE_STEPS + 1):
        capture(client)
    client.request("session.pause")
    client.request("session.resume")
    client.request("session.stop")  # after one of two poses
    status = wait_state(client, "idle")
    assert status.session is None
    reader = SessionReader(Path(started["path"]))
    assert reader.status == "complete" and reader.verify() == []
    assert "pose/0000" in reader.steps() and "pose/0001" not in reader.steps()
    stop = journal_records(reader.path / "journal.jsonl")[-1]
    assert isinstance(stop, SessionStop)
    assert "after 1 of 2 poses" in stop.reason
    states = [t["state"] for t in read_transitions(reader.path)]
    assert states[:3] == ["session_open", "references", "paused"]
    assert states[-2:] == ["stopping", "idle"] and states.count("paused") == 2
    assert json.loads((reader.path / "truth.json").read_text())["microphones"]
    quality = reader.read_json("pose/0000", "quality.json")
    assert quality["checkerboard_found"] == {"cam0": True} and quality["warnings"] == []
    listed = client.request("sessions.list")["sessions"]
    assert [(s["id"], s["status"], s["poses_done"]) for s in listed] == [
        (started["id"], "complete", 1)]


@pytest.mark.slow
def test_abort_at_a_pose_closes_the_session_as_aborted(client: DaemonClient) -> None:
    path = Path(client.request("session.start")["session"]["path"])
    for _ in range(REFERENCE_STEPS):
        capture(client)
    wait_state(client, "waiting_for_pose")
    client.request("session.abort")
    wait_state(client, "idle")
    assert SessionReader(path).status == "aborted"
    assert "resume" not in _refused(client, "session.start", "session_error",
                                    resume=path.name)  # closed for good


def test_failed_quality_check_retries_then_waits_for_the_operator(tmp_path: Path) -> None:
    config = small_config(tmp_path, quality=QualityConfig(min_snr_db=200.0, auto_retries=1))
    running = ThreadDaemon(config)
    try:
        with running.client() as client:
            path = Path(client.request("session.start")["session"]["path"])
            status = capture(client)
            assert status.last_capture is not None
            assert status.last_capture.outcome == "abandoned"
            assert "snr" in status.last_capture.reason and status.state == "references"
            abandoned = [r for r in journal_records(path / "journal.jsonl")
                         if r.kind == "step_abandoned"]
            assert [(r.step, r.attempt) for r in abandoned] == [("reference/0", 1),
                                                                ("reference/0", 2)]
            client.request("session.abort")
            wait_state(client, "idle")
    finally:
        running.stop()


def test_warn_policy_keeps_the_step_with_its_warnings(tmp_path: Path) -> None:
    config = small_config(tmp_path, quality=QualityConfig(min_snr_db=200.0, snr="warn"))
    running = ThreadDaemon(config)
    try:
        with running.client() as client:
            path = Path(client.request("session.start")["session"]["path"])
            status = capture(client)
            assert status.last_capture is not None
            assert status.last_capture.outcome == "complete"
            assert status.last_capture.warnings and "snr" in status.last_capture.warnings[0]
            client.request("session.abort")
            wait_state(client, "idle")
        quality = SessionReader(path).read_json("reference/0", "quality.json")
        assert quality["warnings"] == status.last_capture.warnings
    finally:
        running.stop()


@pytest.mark.slow
def test_camera_failure_and_redo_wait_for_a_new_capture(daemon: ThreadDaemon,
                                                        client: DaemonClient) -> None:
    path = Path(client.request("session.start")["session"]["path"])
    for _ in range(REFERENCE_STEPS - 1):
        capture(client)
    camera = daemon.hardware.cameras[0]
    assert isinstance(camera, SimulatedCamera)  # the daemon runs the simulated world
    camera.fail_next_grabs = 1
    status = capture(client)
    assert status.last_capture is not None
    assert status.last_capture.outcome == "abandoned" and status.step == "refmic"
    assert "CameraTimeoutError" in status.last_capture.reason
    last = capture(client).last_capture
    assert last is not None and last.outcome == "complete"

    group = daemon.hardware.group
    assert group is not None
    original = group.acquire
    calls = {"n": 0}

    def acquire_then_redo(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:  # the second burst of pose 0: the operator asks to redo
            daemon.daemon._handle(RedoRequest())
        return original(*args, **kwargs)

    group.acquire = acquire_then_redo  # type: ignore[method-assign]  # asks for a redo
    status = capture(client)
    assert status.last_capture is not None
    assert status.last_capture.outcome == "abandoned"
    assert "redo" in status.last_capture.reason and status.state == "waiting_for_pose"
    last = capture(client).last_capture
    assert last is not None and last.outcome == "complete"
    assert SessionReader(path).steps()["pose/0000"].attempt == 2
    client.request("session.abort")
    wait_state(client, "idle")


@pytest.mark.slow
def test_hands_free_captures_poses_held_still(tmp_path: Path) -> None:
    config = small_config(tmp_path, hands_free=HandsFreeConfig(
        enabled=True, still_s=0.1, check_interval_s=0.02))
    running = ThreadDaemon(config)
    try:
        with running.client() as client:
            path = Path(client.request("session.start", poses=2)["session"]["path"])
            for _ in range(REFERENCE_STEPS):
                capture(client)  # references are never hands-free
            client.wait_until(lambda s: s.session is None, 60.0)
            reader = SessionReader(path)
            assert reader.status == "complete"
            reasons = [t["reason"] for t in read_transitions(path)]
            assert sum("hands-free" in r for r in reasons) == 2
    finally:
        running.stop()


def test_resume_refuses_another_configuration_and_missing_sessions(
        daemon: ThreadDaemon, client: DaemonClient) -> None:
    other = build_simulated_capture(SimulationOptions(array="planar64", poses=2))
    root = daemon.config.session_root
    SessionWriter.create(root / "foreign", capture=other.config.model_dump(mode="json")).close()
    assert "another hardware configuration" in _refused(client, "session.start",
                                                        "session_error", resume="foreign")
    assert "not a micam session" in _refused(client, "session.start", "session_error",
                                             resume="nothing-here")
    (root / "foreign" / "journal.jsonl").write_text("damaged\nlines\n")
    listed = _listing_once_rescanned(client)  # a change by others shows after the next scan
    assert listed["sessions"] == [] and "foreign" in listed["problems"][0]
    assert "has 3 poses" in _refused(client, "session.start", "session_error", poses=99)


def _listing_once_rescanned(client: DaemonClient) -> dict:
    """`sessions.list` after the background scan it asks for has run (bounded)."""
    first = client.request("sessions.list")
    for _ in range(500):
        time.sleep(0.01)
        listed = client.request("sessions.list")
        if listed != first:
            return listed
    return first


@pytest.mark.slow
def test_curve_lets_in_only_authorised_clients(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    make_keys(keys)
    stranger = tmp_path / "stranger"
    make_keys(stranger)
    sockets = SocketsConfig(control=f"ipc://{tmp_path}/control",
                            events=f"ipc://{tmp_path}/events",
                            curve=CurveConfig(server_secret_key=keys / "server.key_secret",
                                              authorized_clients=keys / "authorized"))
    running = ThreadDaemon(small_config(tmp_path, sockets=sockets))
    try:
        control = sockets.control
        with DaemonClient(control, timeout_s=10, server_key=keys / "server.key",
                          client_key=keys / "client.key_secret") as good:
            assert good.request("ping")["pong"] is True
        for client_key in (stranger / "client.key_secret", None):
            server_key = keys / "server.key" if client_key else None
            with DaemonClient(control, timeout_s=0.5, server_key=server_key,
                              client_key=client_key) as bad, \
                    pytest.raises(DaemonError, match="no reply"):
                bad.request("ping")
    finally:
        running.stop()
