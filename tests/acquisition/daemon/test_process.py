"""The daemon as a process: driven through the CLI, killed at the worst moments, stopped by
SIGTERM, refusing bad configurations. Readiness and crash points are notify-socket handshakes.
"""

from __future__ import annotations

import hashlib
import signal
import sys
from pathlib import Path

import pytest

from acquisition.contracts.capture_config import CaptureConfig
from micam.cli import main
from micam.schemas import shipped
from acquisition.daemon.translog import read_transitions
from acquisition.sequencer import plan_steps
from acquisition.contracts.session import SessionReader, journal_records

from .helpers import DaemonProcess, capture, capture_all, write_toml

HARNESS = Path(__file__).with_name("crash_harness.py")
REFERENCE_STEPS = 7


def _start(tmp_path: Path, script: list[str] | None = None) -> DaemonProcess:
    config = tmp_path / "daemon.toml"
    if not config.exists():
        write_toml(config, tmp_path)
    process = DaemonProcess(config, tmp_path, script=script)
    process.wait_message("READY=1")
    return process


def _stop(process: DaemonProcess) -> None:
    process.proc.send_signal(signal.SIGTERM)
    assert process.wait_exit() == 0


def _files(reader: SessionReader) -> dict[str, tuple[int, dict[str, str]]]:
    """Each completed step: its attempt and its files' checksums, as journaled."""
    return {step: (record.attempt, {n: f.sha256 for n, f in record.files.items()})
            for step, record in reader.steps().items()}


@pytest.mark.slow
def test_session_driven_through_the_cli(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    process = _start(tmp_path)
    control = ["--control", f"ipc://{tmp_path}/control"]
    try:
        assert main(["session", "start", "--poses", "3", *control]) == 0
        assert "started" in capsys.readouterr().out
        outputs = []
        for _ in range(REFERENCE_STEPS + 3):
            assert main(["capture", *control]) == 0
            outputs.append(capsys.readouterr().out)
        assert "rms" in outputs[0] and "SNR" in outputs[0]  # levels shown live
        assert "checkerboard found" in outputs[-1] and "the session closed" in outputs[-1]
        assert main(["sessions", *control]) == 0
        listing = capsys.readouterr().out
        assert "complete" in listing and "3/3" in listing
        assert main(["session", "status", *control]) == 0
        assert "idle" in capsys.readouterr().out
        assert main(["watch", "--duration", "0.2", *control]) == 0
        assert "state     idle" in capsys.readouterr().out
        assert main(["session", "stop", *control]) == 2  # nothing open
        assert "no session is open" in capsys.readouterr().err
    finally:
        _stop(process)
    (session,) = (tmp_path / "sessions").iterdir()
    reader = SessionReader(session)
    assert reader.status == "complete" and reader.verify() == []
    config = CaptureConfig.model_validate(reader.capture)
    assert list(reader.steps()) == [s.id for s in plan_steps(config)] and config.n_poses == 3
    for step, record in reader.steps().items():
        assert "quality.json" in record.files, step
    assert (session / "truth.json").is_file()
    transitions = read_transitions(session)
    assert transitions[0]["state"] == "session_open" and transitions[-1]["state"] == "idle"
    assert main(["inspect", str(session)]) == 0


@pytest.mark.parametrize(("point", "nth"), [("burst", 8), ("between_files", 9),
                                            ("manifest", 9)])
@pytest.mark.slow
def test_sigkill_then_resume_keeps_every_completed_recording(tmp_path: Path, point: str,
                                                              nth: int) -> None:
    process = _start(tmp_path, [sys.executable, str(HARNESS), point, str(nth)])
    try:
        with process.client() as client:
            path = Path(client.request("session.start", poses=2)["session"]["path"])
            for _ in range(REFERENCE_STEPS):
                capture(client)
            client.request("capture")  # pose/0000: the daemon stops dead inside it
        process.wait_message(f"CRASHPOINT={point}")
    finally:
        process.kill()
    reader = SessionReader(path)
    assert reader.status == "interrupted"
    before = _files(reader)
    assert len(before) == REFERENCE_STEPS + (point == "manifest")

    process = _start(tmp_path)
    try:
        with process.client() as client:
            assert client.request("session.start", resume="last")["session"]["id"] == path.name
            capture_all(client)
    finally:
        _stop(process)
    reader = SessionReader(path)
    assert reader.status == "complete"
    assert reader.verify() == []
    after = _files(reader)
    assert {s: after[s] for s in before} == before  # same attempts, same bytes
    assert set(after) == {s.id for s in plan_steps(CaptureConfig.model_validate(reader.capture))}
    ends = [r.step for r in journal_records(path / "journal.jsonl") if r.kind == "step_end"]
    assert len(ends) == len(set(ends))  # nothing recorded twice
    assert after["pose/0000"][0] == (1 if point == "manifest" else 2)
    assert not list(path.rglob("*.partial"))
    for name, digest in after["pose/0000"][1].items():
        file = path / reader.steps()["pose/0000"].dir / name
        assert hashlib.sha256(file.read_bytes()).hexdigest() == digest


@pytest.mark.slow
def test_sigterm_ends_the_burst_and_leaves_the_session_resumable(tmp_path: Path) -> None:
    """`systemctl stop` never loses more than a crash: the step in progress is abandoned after
    its burst, the session stays interrupted, and the next daemon offers it and continues it."""
    process = _start(tmp_path, [sys.executable, str(HARNESS), "burst", "8"])
    with process.client() as client:
        path = Path(client.request("session.start", poses=2)["session"]["path"])
        for _ in range(REFERENCE_STEPS):
            capture(client)
        client.request("capture")
    process.wait_message("CRASHPOINT=burst")
    process.proc.send_signal(signal.SIGTERM)
    process.wait_message("STOPPING=1")
    assert process.wait_exit() == 0
    reader = SessionReader(path)
    assert reader.status == "interrupted" and reader.verify() == []
    records = journal_records(path / "journal.jsonl")
    assert records[-1].kind == "step_abandoned" and "SIGTERM" in records[-1].reason
    pose_files = [r.path for r in records if r.kind == "file" and r.step == "pose/0000"]
    assert pose_files[-1].endswith("speaker_1.wav")  # the burst in progress was finished
    assert [(r.step, r.attempt) for r in records if r.kind == "step_abandoned"] == [
        ("pose/0000", 1)]

    process = _start(tmp_path)
    try:
        with process.client() as client:
            offered = client.wait_until(lambda s: s.resumable is not None, 30.0)
            assert offered.resumable == path.name and offered.state == "idle"
            assert client.request("session.start", resume="last")["session"]["id"] == path.name
            capture_all(client)
    finally:
        _stop(process)
    reader = SessionReader(path)
    assert reader.status == "complete" and reader.verify() == []
    assert reader.steps()["pose/0000"].attempt == 2


@pytest.mark.slow
def test_resume_at_start_auto_continues_the_interrupted_session(tmp_path: Path) -> None:
    config = write_toml(tmp_path / "daemon.toml", tmp_path, 'resume_at_start = "auto"')
    process = _start(tmp_path)
    with process.client() as client:
        path = Path(client.request("session.start", poses=1)["session"]["path"])
        capture(client)
    process.kill()  # a crash; SIGTERM leaves the same interrupted session
    process = DaemonProcess(config, tmp_path)
    process.wait_message("READY=1")
    try:
        with process.client() as client:
            status = client.wait_until(lambda s: s.session is not None, 30.0)
            assert status.session is not None
            assert status.session.id == path.name and status.state == "references"
            capture_all(client)
    finally:
        _stop(process)
    assert SessionReader(path).status == "complete"


@pytest.mark.parametrize(
    ("extra", "words"),
    [("colour = 1", "colour: unknown key 'colour' at the top level"),
     ("camera_timeout_s = -1", "camera_timeout_s: Input should be greater than 0")],
)
def test_invalid_config_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture, extra: str,
                                   words: str) -> None:
    config = write_toml(tmp_path / "bad.toml", tmp_path, extra)
    assert main(["daemon", "--config", str(config)]) == 2
    assert words in capsys.readouterr().err
    assert main(["daemon", "--check", "--config", str(config)]) == 2


def test_non_loopback_bind_without_keys_is_refused(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture) -> None:
    config = tmp_path / "open.toml"
    config.write_text(f'session_root = "{tmp_path}"\n[sockets]\ncontrol = "tcp://0.0.0.0:5599"\n')
    assert main(["daemon", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert "refusing to bind tcp://0.0.0.0:5599" in err and "--make-keys" in err
    assert not list(tmp_path.glob("*/journal.jsonl"))


def test_check_schemas_and_keys_commands(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    config = write_toml(tmp_path / "good.toml", tmp_path)
    assert main(["daemon", "--check", "--config", str(config)]) == 0
    assert "configuration OK: simulated world" in capsys.readouterr().out
    assert main(["daemon", "--schemas", str(tmp_path / "schemas")]) == 0
    written = {p.name.removesuffix(".schema.json"): p.read_text()
               for p in (tmp_path / "schemas").iterdir()}
    assert {"request", "event", "reply"} <= set(written)
    assert all(text == shipped()[name] for name, text in written.items())  # one writer
    assert main(["daemon", "--make-keys", str(tmp_path / "keys")]) == 0
    assert (tmp_path / "keys" / "authorized" / "client.key").is_file()
