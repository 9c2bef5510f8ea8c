"""The capture sequencer on the simulated world: complete sessions, crashes, hardware failures."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from acquisition.contracts.camera import CameraTimeoutError
from acquisition.sequencer import CaptureSequencer, plan_steps
from acquisition.contracts.session import SessionReader, SessionWriter, journal_records
from acquisition.contracts.session._journal import JournalWriter
from daq import DeviceDisconnectedError
from sim.capture import SimulationOptions, build_simulated_capture, truth_document


def _capture(path: Path, options: SimulationOptions, resume: bool = False):
    sim = build_simulated_capture(options)
    writer = (SessionWriter.resume(path) if resume
              else SessionWriter.create(path, capture=sim.config.model_dump(mode="json")))
    return sim, writer, CaptureSequencer(sim.config, sim.group, sim.cameras, sim.operator, writer)


def _hashes(path: Path) -> dict[str, str]:
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in path.rglob("*") if p.is_file() and p.suffix in (".wav", ".png")}


@pytest.mark.slow
def test_complete_session_round_trips(tmp_path: Path, small_options: SimulationOptions) -> None:
    sim, writer, seq = _capture(tmp_path / "s", small_options)
    seq.run()
    writer.close()
    reader = SessionReader(tmp_path / "s")
    assert reader.status == "complete"
    assert reader.verify() == []
    steps = reader.steps()
    assert list(steps) == [s.id for s in plan_steps(sim.config)]
    n_columns = len(sim.config.columns)
    for k in range(6):
        codes, fs = reader.read_recording(f"reference/{k}", f"speaker_{k}.wav")
        assert codes.shape == (sim.config.burst.n_samples, n_columns) and fs == 96_000
    for pose in range(small_options.poses):
        step = f"pose/{pose:04d}"
        assert set(steps[step].files) == {"cam0.png", *(f"speaker_{k}.wav" for k in range(6))}
        assert reader.read_image(step, "cam0.png").shape == (960, 1280)
    assert reader.capture == sim.config.model_dump(mode="json")
    truth = truth_document(sim)
    assert len(truth["microphones"]) == 48 and len(truth["poses"]) == small_options.poses


def test_recording_carries_the_reference_microphone(tmp_path: Path,
                                                   small_options: SimulationOptions) -> None:
    sim, _, seq = _capture(tmp_path / "s", small_options)
    seq.run()
    reader = SessionReader(tmp_path / "s")
    ref_col = [c.role for c in sim.config.columns].index("reference")
    codes, _ = reader.read_recording("reference/2", "speaker_2.wav")
    ref_rms = codes[:, ref_col].astype(float).std()
    mic_rms = codes[:, :48].astype(float).std(axis=0).max()
    assert ref_rms > 5 * mic_rms  # 2 mm from the speaker against tens of centimetres


class _Crash(BaseException):
    """Stands for the process dying: nothing in the capture code catches it."""


def _count_records(path: Path) -> int:
    return len(journal_records(path / "journal.jsonl"))


@pytest.mark.slow
def test_crash_after_every_journal_record_resumes_intact(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    options = SimulationOptions(array="scatter48", poses=1, mls_order=8, seed=9)
    reference = tmp_path / "reference"
    _, writer, seq = _capture(reference, options)
    seq.run()
    writer.close()
    total = _count_records(reference)
    original_append = JournalWriter.append
    for crash_after in range(1, total):
        path = tmp_path / f"crash{crash_after}"
        calls = {"n": 0}

        def append_then_die(self, record, _calls=calls, _limit=crash_after):
            original_append(self, record)
            _calls["n"] += 1
            if _calls["n"] == _limit:
                self.close()  # as the kernel does for a dead process: the lock is released
                raise _Crash()

        monkeypatch.setattr(JournalWriter, "append", append_then_die)
        with pytest.raises(_Crash):
            _, writer, seq = _capture(path, options)
            seq.run()
        monkeypatch.setattr(JournalWriter, "append", original_append)
        before = _hashes(path)
        reader = SessionReader(path)
        assert reader.status == "interrupted"
        completed_before = {s: r.attempt for s, r in reader.steps().items()}

        _, writer, seq = _capture(path, options, resume=True)
        seq.run()
        writer.close()
        reader = SessionReader(path)
        assert reader.status == "complete", crash_after
        assert reader.verify() == [], crash_after
        after = _hashes(path)
        assert all(after[name] == digest for name, digest in before.items()), crash_after
        steps = reader.steps()
        assert len(steps) == 8
        for step, attempt in completed_before.items():
            assert steps[step].attempt == attempt  # nothing completed is captured twice
        assert not list(path.rglob("*.partial"))


@pytest.mark.slow
def test_unplugged_board_interrupts_and_resume_completes(
        tmp_path: Path, small_options: SimulationOptions) -> None:
    path = tmp_path / "s"
    sim, writer, seq = _capture(path, small_options)
    board = sim.group.boards[2]
    original_read = board.read
    reads = {"n": 0}

    def read_until_unplugged(n, timeout_s):
        reads["n"] += 1
        if reads["n"] == 12:  # inside the first pose, after the six references
            board.faults.unplug_at_sample = 100
        return original_read(n, timeout_s)

    board.read = read_until_unplugged  # type: ignore[method-assign]
    with pytest.raises(DeviceDisconnectedError, match=board.identity.serial):
        seq.run()
    writer.close()
    reader = SessionReader(path)
    assert reader.status == "interrupted"
    assert "pose/0000" not in reader.steps()
    records = journal_records(path / "journal.jsonl")
    assert any(r.kind == "step_abandoned" and "DeviceDisconnectedError" in r.reason
               for r in records)

    _, writer, seq = _capture(path, small_options, resume=True)
    seq.run()
    reader = SessionReader(path)
    assert reader.status == "complete" and reader.verify() == []
    assert reader.steps()["pose/0000"].attempt == 2


def test_camera_without_frame_interrupts_cleanly(tmp_path: Path,
                                                 small_options: SimulationOptions) -> None:
    path = tmp_path / "s"
    sim, writer, seq = _capture(path, small_options)
    sim.cameras[0].fail_next_grabs = 1
    with pytest.raises(CameraTimeoutError, match="cam0"):
        seq.run()
    writer.close()
    assert SessionReader(path).status == "interrupted"
    _, writer, seq = _capture(path, small_options, resume=True)
    seq.run()
    assert SessionReader(path).status == "complete"


@pytest.mark.slow
def test_same_seed_same_recordings(tmp_path: Path, small_options: SimulationOptions) -> None:
    for name in ("a", "b"):
        _, _, seq = _capture(tmp_path / name, small_options)
        seq.run()
    a, b = SessionReader(tmp_path / "a"), SessionReader(tmp_path / "b")
    ra, _ = a.read_recording("pose/0001", "speaker_3.wav")
    rb, _ = b.read_recording("pose/0001", "speaker_3.wav")
    assert np.array_equal(ra, rb)


def test_capture_config_refuses_unknown_keys(small_options: SimulationOptions) -> None:
    from pydantic import ValidationError

    from acquisition.contracts.capture_config import CaptureConfig

    doc = build_simulated_capture(small_options).config.model_dump(mode="json")
    doc["burst"]["mls_ordr"] = 12  # a typo in a hand-written config must not pass silently
    with pytest.raises(ValidationError, match="mls_ordr"):
        CaptureConfig.model_validate(doc)
