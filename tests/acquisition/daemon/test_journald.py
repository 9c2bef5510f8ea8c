"""Structured journal fields: the daemon's records reach journald with the session and step."""

from __future__ import annotations

import logging
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from acquisition.daemon.systemd import configure_logging, set_log_context


def _fields(datagram: bytes) -> dict[str, str]:
    """Parse the native journal protocol (KEY=VALUE lines; KEY, length, value for binary)."""
    fields, rest = {}, datagram
    while rest:
        line, _, after = rest.partition(b"\n")
        if b"=" in line:
            key, _, value = line.partition(b"=")
            fields[key.decode()] = value.decode()
            rest = after
        else:
            size = int.from_bytes(after[:8], "little")
            fields[line.decode()] = after[8:8 + size].decode()
            rest = after[8 + size + 1:]
    return fields


@pytest.fixture
def journal(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[socket.socket]:
    path = tmp_path / "journal.socket"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(5)
    monkeypatch.setenv("JOURNAL_STREAM", "8:1234")
    monkeypatch.setenv("MICAM_JOURNAL_SOCKET", str(path))
    root = logging.getLogger()
    saved = root.handlers[:], root.level
    configure_logging(logging.DEBUG)
    yield sock
    for handler in root.handlers:
        handler.close()
    root.handlers[:], level = saved
    root.setLevel(level)
    set_log_context()
    sock.close()


def test_extra_fields_reach_the_journal(journal: socket.socket) -> None:
    logging.getLogger("micam.daemon").warning("clipped\nsecond line",
                                              extra={"session_id": "s-1", "step": "pose/0003"})
    fields = _fields(journal.recv(65536))
    assert fields["MESSAGE"] == "micam.daemon: clipped\nsecond line"
    assert fields["PRIORITY"] == "4" and fields["SYSLOG_IDENTIFIER"] == "micam"
    assert fields["MICAM_SESSION_ID"] == "s-1" and fields["MICAM_STEP"] == "pose/0003"


def test_the_context_fills_the_fields_and_extra_wins(journal: socket.socket) -> None:
    set_log_context("s-2", "reference/0001")
    logging.getLogger("micam.daemon").info("from the context")
    fields = _fields(journal.recv(65536))
    assert (fields["MICAM_SESSION_ID"], fields["MICAM_STEP"]) == ("s-2", "reference/0001")
    logging.getLogger("micam.daemon").info("own", extra={"step": "pose/0009"})
    assert _fields(journal.recv(65536))["MICAM_STEP"] == "pose/0009"
    set_log_context()
    logging.getLogger("micam.daemon").info("no session")
    assert "MICAM_SESSION_ID" not in _fields(journal.recv(65536))


def test_outside_systemd_the_text_log_names_the_session(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    root = logging.getLogger()
    saved = root.handlers[:], root.level
    try:
        configure_logging(logging.INFO)
        logging.getLogger("micam.daemon").info("hello", extra={"session_id": "s-3"})
        logging.getLogger("micam.daemon").debug("not shown")
    finally:
        root.handlers[:], level = saved
        root.setLevel(level)
    err = capsys.readouterr().err
    assert "micam.daemon: hello [session s-3]" in err and "not shown" not in err


def test_the_text_log_follows_stderr_when_it_is_replaced(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The daemon's text log writes to the stderr of the moment: a stream replaced and
    closed since logging was set up (a test's captured one) takes no record and raises
    nothing."""
    import io
    import sys

    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    root = logging.getLogger()
    saved = root.handlers[:], root.level
    first, second = io.StringIO(), io.StringIO()
    try:
        monkeypatch.setattr(sys, "stderr", first)
        configure_logging(logging.INFO)
        monkeypatch.setattr(sys, "stderr", second)
        first.close()
        monkeypatch.setattr(logging, "raiseExceptions", True)
        logging.getLogger("micam.daemon").info("after the swap")
    finally:
        root.handlers[:], level = saved
        root.setLevel(level)
    assert "micam.daemon: after the swap" in second.getvalue()
