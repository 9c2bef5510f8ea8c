"""micam.testing works as its users would use it: a small session, a daemon in a thread."""

from __future__ import annotations

from pathlib import Path

from acquisition.contracts.session import SessionReader
from micam.testing import ThreadDaemon, record_small_session, small_daemon_config


def test_record_small_session_writes_a_complete_session_with_its_truth(tmp_path: Path) -> None:
    path = record_small_session(tmp_path / "s", poses=1)
    assert SessionReader(path).status == "complete"
    assert (path / "truth.json").is_file()


def test_a_thread_daemon_answers_at_once_and_stops(tmp_path: Path) -> None:
    with ThreadDaemon(small_daemon_config(tmp_path)) as daemon, daemon.client() as client:
        status = client.status()
    assert status.simulated and status.session is None
    assert not daemon.thread.is_alive()
