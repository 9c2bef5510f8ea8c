"""The memo that remembers work by content: bounded, least recently used dropped first."""

from __future__ import annotations

from pathlib import Path

import pytest

from calibration.memo import LruMemo


def test_the_least_recently_used_is_dropped() -> None:
    memo: LruMemo[str, int] = LruMemo(2)
    memo.put("a", 1)
    memo.put("b", 2)
    assert memo.get("a") == 1  # "b" is now the least recently used
    memo.put("c", 3)
    assert (memo.get("a"), memo.get("b"), memo.get("c"), len(memo)) == (1, None, 3, 2)


def test_a_memo_holds_something() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        LruMemo(0)


def test_a_worker_owns_its_detections(tmp_path: Path) -> None:
    """Each worker has its own memo of checkerboard detections (not the process's)."""
    from calibration.camera_calibration import PROCESS_DETECTIONS
    from calibration.worker.worker import Worker, WorkerSettings

    settings = WorkerSettings(jobs="ipc:///nowhere/jobs", files="ipc:///nowhere/files",
                              cache=tmp_path / "cache")
    a, b = Worker(settings), Worker(settings)
    try:
        assert a.detections is not b.detections and a.detections is not PROCESS_DETECTIONS
    finally:
        for w in (a, b):
            w._context.term()
