"""The session index behind `sessions.list`: journals are read by a background thread that
waits while a step is captured, never by a listing; the index survives a restart."""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import pytest

import acquisition.daemon.index as index_module
from acquisition.daemon.index import SessionIndex
from acquisition.contracts.session import SessionWriter
from sim.capture import SimulationOptions, build_simulated_capture

WAIT_S = 30.0


@pytest.fixture(scope="module")
def capture() -> dict:
    options = SimulationOptions(array="scatter48", poses=2, mls_order=9)
    return build_simulated_capture(options).config.model_dump(mode="json")


def _sessions(root: Path, capture: dict, names: list[str]) -> None:
    for name in names:
        writer = SessionWriter.create(root / name, capture=capture, session_id=name)
        if name.endswith("done"):
            writer.stop("aborted", "test")
        else:
            writer.close()


def _no_reading(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(_path: Path) -> None:
        raise AssertionError("a journal was read")

    monkeypatch.setattr(index_module, "SessionReader", refuse)


def _listed(index: SessionIndex) -> dict[str, str]:
    return {s["id"]: s["status"] for s in index.listing().sessions}


def test_a_listing_reads_no_journal(tmp_path: Path, capture: dict,
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    _sessions(tmp_path, capture, ["a", "b-done", "c"])
    index = SessionIndex(tmp_path)
    index.start()
    try:
        assert index.wait_complete(WAIT_S)
        _no_reading(monkeypatch)
        assert _listed(index) == {"a": "interrupted", "b-done": "aborted", "c": "interrupted"}
        assert index.newest_interrupted() == "c"
    finally:
        index.close()


def test_changes_by_others_appear_after_the_next_scan(tmp_path: Path, capture: dict) -> None:
    _sessions(tmp_path, capture, ["a", "b"])
    index = SessionIndex(tmp_path)
    index.start()
    try:
        assert index.wait_complete(WAIT_S)
        _sessions(tmp_path, capture, ["c"])
        shutil.rmtree(tmp_path / "a")
        (tmp_path / "b" / "journal.jsonl").write_text("damaged\n")
        index._wake.set()  # what a listing does (at most once a second)
        for _ in range(3000):
            listing = index.listing()
            if [s["id"] for s in listing.sessions] == ["c"]:
                break
            time.sleep(0.01)
        assert [s["id"] for s in listing.sessions] == ["c"]
        assert len(listing.problems) == 1 and listing.problems[0].startswith("b: ")
    finally:
        index.close()


def test_the_index_waits_while_a_step_is_captured(tmp_path: Path, capture: dict) -> None:
    _sessions(tmp_path, capture, ["a"])
    capturing = [True]
    index = SessionIndex(tmp_path, busy=lambda: capturing[0])
    index.start()
    try:
        assert not index.wait_complete(0.3) and _listed(index) == {}
        capturing[0] = False
        assert index.wait_complete(WAIT_S) and _listed(index) == {"a": "interrupted"}
    finally:
        index.close()


def test_a_restart_reads_only_what_changed(tmp_path: Path, capture: dict,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    root = tmp_path / "sessions"
    root.mkdir()
    _sessions(root, capture, ["a", "b-done"])
    first = SessionIndex(root)
    first.start()
    assert first.wait_complete(WAIT_S)
    first.close()
    assert first.file.is_file() and not list(root.glob("*.json"))
    _no_reading(monkeypatch)
    again = SessionIndex(root)
    again.start()
    try:
        assert again.wait_complete(WAIT_S)
        assert _listed(again) == {"a": "interrupted", "b-done": "aborted"}
    finally:
        again.close()


def test_a_damaged_index_file_is_ignored(tmp_path: Path, capture: dict) -> None:
    root = tmp_path / "sessions"
    root.mkdir()
    _sessions(root, capture, ["a"])
    root.with_name("sessions.index.json").write_text('{"version": 1, "entries": {"../x": 1}}')
    index = SessionIndex(root)
    index.start()
    try:
        assert index.wait_complete(WAIT_S) and _listed(index) == {"a": "interrupted"}
    finally:
        index.close()
