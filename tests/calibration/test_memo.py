"""The memo that remembers work by content: bounded, least recently used dropped first."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
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


def test_a_memo_never_remembers_a_board_predicted_to_run_off_its_image(monkeypatch) -> None:
    """Whether an unsure image's board runs off the image is predicted from the other images
    of the calibration, so it is not the image's alone: a worker's live job with few poses
    may search an image robustly that the final job predicts cut. The final job must then
    find what `micam calibrate` finds (no board there), not what the live job remembered;
    else the worker's result depended on which live jobs it had run."""
    from calibration.camera import camera_calibration as cc
    from calibration.camera.corners import UNSURE

    corners = np.zeros((4, 2))
    monkeypatch.setattr(cc, "detect_corners_quickly", lambda image, board: UNSURE)
    monkeypatch.setattr(cc, "detect_corners_robustly", lambda image, board: corners)
    key = ("cam0", "pose/0000")
    image = np.zeros((48, 64), np.uint8)
    memo = cc.DetectionMemo(10)

    def detect(cut: set, with_memo: bool) -> dict:
        monkeypatch.setattr(cc, "_runs_off_the_image", lambda *args: cut)
        return cc._detect_all([key], lambda _: image, {key: "sha"}, memo if with_memo else None,
                              ["cam0"], None, None, 1, 1)  # type: ignore[arg-type]

    assert detect(set(), with_memo=True)[key][0] is corners  # the live job: searched, found
    no_board = {key: (None, (64, 48))}
    assert detect({key}, with_memo=True) == detect({key}, with_memo=False) == no_board
    assert detect(set(), with_memo=True)[key][0] is corners  # the robust search is remembered
