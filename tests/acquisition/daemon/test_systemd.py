"""Unit tests of the dependency-free sd_notify sender and the watchdog period."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest

from acquisition.daemon.systemd import Watchdog, sd_notify


def test_no_socket_is_a_no_op(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    assert sd_notify("READY=1") is False


def test_path_socket(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "notify"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind(str(path))
        server.settimeout(5)
        monkeypatch.setenv("NOTIFY_SOCKET", str(path))
        assert sd_notify("READY=1", "STATUS=idle")
        assert server.recv(1024) == b"READY=1\nSTATUS=idle"


def test_abstract_socket(monkeypatch: pytest.MonkeyPatch) -> None:
    name = f"micam-test-{os.getpid()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as server:
        server.bind("\0" + name)
        server.settimeout(5)
        monkeypatch.setenv("NOTIFY_SOCKET", "@" + name)
        assert sd_notify("WATCHDOG=1")
        assert server.recv(1024) == b"WATCHDOG=1"


def test_gone_socket_is_not_an_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NOTIFY_SOCKET", str(tmp_path / "gone"))
    assert sd_notify("READY=1") is False


def test_watchdog_pings_at_half_the_period(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("WATCHDOG_USEC", "30000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    assert Watchdog().interval_s == pytest.approx(15.0)
    monkeypatch.setenv("WATCHDOG_PID", "1")  # meant for another process
    assert Watchdog().interval_s is None
    monkeypatch.delenv("WATCHDOG_USEC")
    assert Watchdog().interval_s is None
