"""The memo that remembers work by content: bounded, least recently used dropped first."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from acquisition.contracts.session import SessionError, SessionReader
from calibration.memo import LruMemo
from calibration.pipeline import measure


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


def test_a_worker_owns_its_memo(tmp_path: Path) -> None:
    """Each worker has its own memo of detections and delays (nothing is process-wide)."""
    from calibration.worker.worker import Worker, WorkerSettings

    settings = WorkerSettings(jobs="ipc:///nowhere/jobs", files="ipc:///nowhere/files",
                              cache=tmp_path / "cache")
    a, b = Worker(settings), Worker(settings)
    try:
        assert a.memo is not b.memo and a.memo.detections is not b.memo.detections
    finally:
        for w in (a, b):
            w._context.term()


def _damage(session: Path, step: str, name: str) -> None:
    path = session / SessionReader(session).steps()[step].files[name].path
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("name", ["cam0.png", "speaker_1.wav"])
def test_without_a_memo_every_file_is_read_again(small_session: Path, tmp_path: Path,
                                                 name: str) -> None:
    """A caller without a memo (`micam calibrate`) reads and checks every file on every
    calibration: a file damaged after an earlier calibration in the same process is refused."""
    session = tmp_path / "s"
    shutil.copytree(small_session, session)
    measure(session)
    _damage(session, "pose/0001", name)
    with pytest.raises(SessionError, match=rf"{name} \(step 'pose/0001'\): checksum mismatch"):
        measure(session)
