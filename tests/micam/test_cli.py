"""The command line as a new user meets it: every failure one line and a documented status,
--version, help on every option, one endpoint name, pure --json, a quiet --quiet, log levels."""

from __future__ import annotations

import argparse
import json
import re
from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

import micam.cli as cli
from acquisition.contracts.protocol import LastCapture, SessionSummary, StateEvent, StatusResult
from micam.cli import build_parser, main
from micam.testing import FakeDaemonClient

README = Path(__file__).resolve().parents[2] / "README.md"


def _subparsers(parser: argparse.ArgumentParser, path: str = "micam"):
    """Every parser of the command line, with its command path."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _subparsers(sub, f"{path} {name}")


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith("micam ")


def test_every_option_of_every_command_has_help() -> None:
    missing = [f"{path} {'/'.join(a.option_strings) or a.dest}"
               for path, parser in _subparsers(build_parser()) for a in parser._actions
               if not isinstance(a, argparse._SubParsersAction)
               and a.help != argparse.SUPPRESS and not (a.help or "").strip()]
    assert not missing, f"options without help: {missing}"


def test_every_exit_status_is_documented_in_the_readme() -> None:
    text = README.read_text()
    for name in dir(cli):
        if name.startswith("EXIT_"):
            assert f"| {getattr(cli, name)} |" in text, f"{name} is not in README's table"


def _failing(monkeypatch: pytest.MonkeyPatch, error: BaseException) -> None:
    """`micam inspect` raising `error` when it runs."""
    from micam.commands import inspect_session

    def run(_args: argparse.Namespace) -> int:
        raise error

    monkeypatch.setattr(inspect_session, "run", run)


def test_an_unexpected_error_is_one_line_with_status_70_and_its_traceback_in_the_bug_log(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        tmp_path: Path) -> None:
    monkeypatch.setenv(cli.BUG_DIR_ENV, str(tmp_path / "bugs"))
    _failing(monkeypatch, RuntimeError("the first line\nthe second"))
    assert main(["inspect", "somewhere"]) == cli.EXIT_INTERNAL
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("micam: error: the first line; the second")
    assert "Traceback" not in err and "this is a bug in micam" in err
    [log] = (tmp_path / "bugs").iterdir()
    assert f"the traceback is in {log}" in err
    text = log.read_text()
    assert "inspect somewhere" in text and "Traceback (most recent call last)" in text
    assert "RuntimeError: the first line" in text and "raise error" in text


def test_a_bug_log_that_cannot_be_written_points_at_debug(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    monkeypatch.setenv(cli.BUG_DIR_ENV, str(tmp_path / "file" / "bugs"))
    _failing(monkeypatch, RuntimeError("boom"))
    assert main(["inspect", "somewhere"]) == cli.EXIT_INTERNAL
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run again with --debug for the traceback" in err


def test_debug_shows_the_traceback(monkeypatch: pytest.MonkeyPatch) -> None:
    _failing(monkeypatch, RuntimeError("boom"))
    with pytest.raises(RuntimeError, match="boom"):
        main(["inspect", "somewhere", "--debug"])
    with pytest.raises(RuntimeError, match="boom"):
        main(["--debug", "inspect", "somewhere"])


def test_a_closed_output_pipe_ends_quietly_with_141(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _failing(monkeypatch, BrokenPipeError())
    assert main(["inspect", "somewhere"]) == cli.EXIT_PIPE_CLOSED
    assert capsys.readouterr().err == ""


def test_a_user_error_is_status_2(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["inspect", str(tmp_path / "nothing")]) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert err.startswith("micam: error: ") and err.count("\n") == 1


@pytest.mark.parametrize("command", [["watch"], ["capture"], ["session", "status"],
                                     ["worker"]])
def test_a_bad_daemon_endpoint_is_refused_before_connecting(
        command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main([*command, "--control", "http://localhost:8765"])
    assert exit_.value.code == cli.EXIT_USAGE
    assert "not a daemon endpoint; write tcp://HOST:PORT or ipc://PATH" in capsys.readouterr().err


def test_the_daemon_endpoint_has_one_name_and_connect_stays_a_hidden_alias() -> None:
    parser = build_parser()
    assert parser.parse_args(["worker", "--connect", "ipc:///x/control"]).control \
        == "ipc:///x/control"
    assert parser.parse_args(["worker", "--control", "tcp://h:5555"]).control == "tcp://h:5555"
    assert parser.parse_args(["watch", "--control", "tcp://h:5555"]).control == "tcp://h:5555"
    worker = dict(_subparsers(parser))["micam worker"]
    assert "--connect" not in worker.format_help()


def test_log_level_from_the_option_or_the_environment(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    import logging

    seen: dict[str, Any] = {}
    from micam.commands import inspect_session

    def run(args: argparse.Namespace) -> int:
        seen["level"] = args.log_level
        seen["root"] = logging.getLogger().level
        return 0

    monkeypatch.setattr(inspect_session, "run", run)
    assert main(["inspect", "x", "--log-level", "debug"]) == 0
    assert seen == {"level": logging.DEBUG, "root": logging.DEBUG}
    monkeypatch.setenv("MICAM_LOG_LEVEL", "warning")
    assert main(["inspect", "x"]) == 0 and seen["level"] == logging.WARNING
    monkeypatch.setenv("MICAM_LOG_LEVEL", "chatty")
    assert main(["inspect", "x"]) == cli.EXIT_USAGE
    assert "MICAM_LOG_LEVEL='chatty'" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["calibrate", "SESSION", "--out", "{tmp}/result.json", "--acoular-xml", "{tmp}/f/mics.xml"],
    ["calibrate", "SESSION", "--out", "{tmp}/f/no/result.json"],
    ["image", "SESSION", "--geometry", "g.json", "--pose", "0", "--speaker", "0", "--band",
     "8000", "--out", "{tmp}/f/map.png"],
    ["evaluate-imaging", "SESSION", "--geometry", "g.json", "--json", "{tmp}/f/e.json"],
])
def test_outputs_are_checked_before_any_work(argv: list[str], tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """The session does not even exist: the unwritable output (under a file) is found first."""
    (tmp_path / "f").write_text("a file")
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert "not a directory" in err and err.count("\n") == 1
    assert [p.name for p in tmp_path.iterdir()] == ["f"]


def test_every_out_makes_its_missing_parents(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """docs: `micam config template import --out lab/import.toml` with no lab/ yet."""
    out = tmp_path / "lab" / "deeper" / "import.toml"
    assert main(["config", "template", "import", "--out", str(out)]) == 0, \
        capsys.readouterr().err
    assert out.is_file() and out.stat().st_size > 0


def test_an_output_that_is_a_directory_is_refused(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", "SESSION", "--out", str(tmp_path)]) == cli.EXIT_USAGE
    assert "is a directory; name a file" in capsys.readouterr().err


def test_daq_selftest_without_libusb_is_one_line(monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    import usb.core

    import daq.usb

    def no_backend(**_kwargs: object) -> list:
        raise usb.core.NoBackendError("No backend available")

    monkeypatch.setattr(daq.usb, "open_boards", no_backend)
    assert main(["daq", "selftest"]) == cli.EXIT_USAGE
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "libusb-1.0" in err


# -- the daemon's clients, against a fake client --------------------------------------------


def _status(**fields: Any) -> StatusResult:
    return StatusResult(**{"state": "idle", "simulated": True,
                           "events_endpoint": "ipc:///x/events", "last_event_seq": 0, **fields})


def _event(seq: int) -> StateEvent:
    return StateEvent(seq=seq, time_utc=datetime.now(UTC), state="idle", previous="idle",
                      reason="test")


def _fake_daemon(monkeypatch: pytest.MonkeyPatch, client: FakeDaemonClient) -> None:
    import acquisition.daemon.client

    monkeypatch.setattr(acquisition.daemon.client, "client_from_args", lambda _args: client)


def test_watch_json_is_pure_json_and_a_restart_is_not_negative_missed_events(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    events = [_event(120), _event(121), _event(0), _event(3)]
    _fake_daemon(monkeypatch, FakeDaemonClient(_status(), events))
    assert main(["watch", "--json", "--count", "4"]) == 0
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert len(lines) == 5 and all(isinstance(json.loads(line), dict) for line in lines)
    assert "restarted" in err and "missed 2 events" in err and "-" not in err.split("missed")[1]


def test_watch_text_says_the_daemon_restarted(monkeypatch: pytest.MonkeyPatch,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    _fake_daemon(monkeypatch, FakeDaemonClient(_status(), [_event(122), _event(0)]))
    assert main(["watch", "--count", "2"]) == 0
    out = capsys.readouterr().out
    assert "the daemon restarted" in out and "missed -" not in out


def test_watch_says_target_reached_only_while_its_session_is_open(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """A worker's live calibration may arrive after stop: "you may stop" is then wrong."""
    from acquisition.contracts.job_messages import LiveUpdate
    from acquisition.contracts.protocol import LiveCalibrationEvent

    session = SessionSummary(id="s1", path="/s1", status="open", steps_done=9, steps_total=9,
                             poses_done=2, n_poses=2, created_utc=datetime.now(UTC))
    update = LiveUpdate(session_id="s1", poses=2, microphones=[], mean_uncertainty_m=1e-4,
                        predicted_accuracy_m=1e-4, speed_of_sound_m_s=343.0)

    def live(seq: int) -> LiveCalibrationEvent:
        return LiveCalibrationEvent(seq=seq, time_utc=datetime.now(UTC), session_id="s1",
                                    job_id="s1.live-to-p0001", update=update)

    closed = StateEvent(seq=2, time_utc=datetime.now(UTC), state="idle", previous="stopping",
                        reason="stopped", session_id="s1")
    _fake_daemon(monkeypatch, FakeDaemonClient(_status(state="waiting_for_pose",
                                                       session=session),
                                               [live(1), closed, live(3)]))
    assert main(["watch", "--count", "3", "--target-mm", "0.5"]) == 0
    out = capsys.readouterr().out
    assert out.count("REACHED") == 1
    assert out.index("REACHED") < out.index("stopped")


def test_capture_quiet_prints_only_the_outcome(monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    session = SessionSummary(id="s", path="/s", status="open", steps_done=1, steps_total=9,
                             poses_done=0, n_poses=2, created_utc=datetime.now(UTC))
    status = _status(session=session,
                     last_capture=LastCapture(number=1, step="pose/0000", outcome="complete"))
    _fake_daemon(monkeypatch, FakeDaemonClient(status, [_event(5)],
                                                {"capture": {"number": 1, "step": "pose/0000"}}))
    assert main(["capture", "--quiet"]) == 0
    assert capsys.readouterr().out == "pose/0000 complete\n"
    assert main(["capture"]) == 0
    assert len(capsys.readouterr().out.splitlines()) > 1


def test_the_summary_of_a_method_without_uncertainties_prints_no_nan() -> None:
    from calibration.report import summary_lines

    nan = float("nan")
    result = SimpleNamespace(
        microphones=[SimpleNamespace(std_m=[nan, nan, nan])] * 3, poses=[0, 1],
        method="paper", speed_of_sound_m_s=343.2, speed_of_sound_std_m_s=nan,
        residuals=SimpleNamespace(rms_s=1e-8), timings_s={"solver": 1.0}, camera_frozen=None,
        left_out_microphones=set, cameras=[], board_bow=None)
    text = "\n".join(summary_lines(SimpleNamespace(result=result,  # type: ignore[arg-type]
                                                   data=SimpleNamespace(n_speakers=6))))
    assert "nan" not in text and "no position std (method paper gives none)" in text


def test_the_fake_client_records_requests_and_refuses_unknown_ones() -> None:
    fake = FakeDaemonClient(_status(), replies={"redo": {"step": "pose/0001"}})
    assert fake.request("redo") == {"step": "pose/0001"}
    assert fake.requests == [("redo", {})]
    with pytest.raises(KeyError, match="no reply for 'capture'"):
        fake.request("capture")


def test_the_parser_loads_nothing_heavy() -> None:
    """`micam --help` is instant: building the parser (every subcommand's options, the
    simulated mistakes' list included) imports neither numpy, OpenCV, SciPy nor the
    simulated world, and of the calibration only its named choices (calibration.choices:
    the latency models and stages, which imports nothing)."""
    import subprocess
    import sys

    light = "{'calibration', 'calibration.choices'}"
    code = ("import sys; from micam.cli import build_parser; build_parser(); "
            f"print(sorted({{m.split('.')[0] for m in set(sys.modules) - {light}}} "
            "& {'numpy', 'cv2', 'scipy', 'calibration', 'matplotlib', 'zmq', 'sim'}))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True).stdout.strip()
    assert loaded == "[]", f"building the parser loads {loaded}"


def test_sigterm_to_simulate_ends_it_as_interrupted_and_resumable(tmp_path: Path) -> None:
    """README "Exit status": 3 for an interrupted `simulate`, whatever interrupted it."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "s"
    proc = subprocess.Popen([sys.executable, "-m", "micam.cli", "simulate", "--out", str(out),
                             "--array", "scatter48", "--poses", "20", "--mls-order", "9",
                             "--quiet"], stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(Path(cli.__file__).parents[1])})
    assert proc.stderr is not None
    deadline = time.monotonic() + 60
    while not list(out.glob("references/*")):  # a step under way: the capture has begun
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == cli.EXIT_INCOMPLETE, err
    assert "terminated (SIGTERM)" in err and f"micam simulate --resume --out {out}" in err


@pytest.mark.parametrize("action", ["abort", "stop"])
def test_session_abort_and_stop_say_which_session_closed(
        action: str, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The daemon closes an aborted session at once: the status after the request has no
    session any more, and the command used to print nothing."""
    session = SessionSummary(id="s7", path="/s7", status="open", steps_done=3, steps_total=9,
                             poses_done=0, n_poses=2, created_utc=datetime.now(UTC))
    client = FakeDaemonClient(_status(state="waiting_for_pose", session=session))

    def closed(**_args: object) -> dict:
        client._status = _status()  # closed before the command returns
        return {}

    client.replies[f"session.{action}"] = closed
    _fake_daemon(monkeypatch, client)
    assert main(["session", action]) == 0
    assert capsys.readouterr().out == f"session s7 closed ({action})\n"


def test_rates_read_as_people_write_them(capsys: pytest.CaptureFixture[str]) -> None:
    from micam.commands.daq import rate_text

    assert [rate_text(r) for r in (500, 96_000, 2_730_511)] == ["500 S/s", "96 kS/s",
                                                               "2.73 MS/s"]
    assert main(["daq", "selftest", "--emulate", "--seconds", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "at 96 kS/s (emulated, not paced: read at " in out, out
    assert not re.search(r"\d{5,} S/s", out), out


def _command_paths(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
                   ) -> list[tuple[str, ...]]:
    paths = [path]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                paths += _command_paths(child, (*path, name))
    return paths


def test_every_command_has_version(capsys: pytest.CaptureFixture[str]) -> None:
    """README: "Every command has `--help` ... and `--version`" (`micam capture` had not)."""
    paths = _command_paths(build_parser())
    assert ("capture",) in paths and ("session", "start") in paths and len(paths) >= 40
    for path in paths:
        with pytest.raises(SystemExit) as ended:
            main([*path, "--version"])
        assert ended.value.code == 0, path
        assert capsys.readouterr().out.startswith("micam "), path
