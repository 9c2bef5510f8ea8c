"""Tests of the crash-safe session store (acquisition.session).

The crash tests run a small scripted session in a child process that dies with os._exit at the
k-th occurrence of a chosen point (a journal append, a rename, a mkdir), for every k; the parent
then resumes the session, finishes it and checks that nothing completed was lost or changed.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import multiprocessing
import os
import traceback
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import soundfile as sf

from acquisition.contracts.session import (
    JOURNAL_NAME,
    MANIFEST_NAME,
    Record,
    SessionError,
    SessionManifest,
    SessionReader,
    SessionWriter,
    StepEnd,
    _writer,
    attempt_dir,
    journal_records,
)
from acquisition.contracts.session._journal import JournalWriter, scan_journal

CAPTURE = {
    "channel_map": [{"board": "DT9836-A", "input": i, "mic": i} for i in range(80)],
    "volts_per_code": 10.0 / 32768,
    "sample_rate_hz": 48000,
}
SCRIPT_STEPS = ("refmic", "pose/0000")
CRASHED = 17  # exit code of a child that reached its crash point


# -- deterministic content ------------------------------------------------------------------------


def _seed(step: str) -> int:
    return int.from_bytes(hashlib.sha256(step.encode()).digest()[:4], "little")


def _codes(step: str, n_samples: int = 64, n_channels: int = 80) -> np.ndarray:
    rng = np.random.default_rng(_seed(step))
    codes = rng.integers(-32768, 32768, size=(n_samples, n_channels), dtype=np.int16)
    codes[0, 0], codes[1, 0] = -32768, 32767  # both extremes must survive
    return codes


def _image(step: str, colour: bool = True) -> np.ndarray:
    shape = (12, 16, 3) if colour else (12, 16)
    return np.random.default_rng(_seed(step) + 1).integers(0, 256, size=shape, dtype=np.uint8)


def _record_step(writer: SessionWriter, step: str) -> None:
    """One scripted step: begin, a recording, an image and a JSON record, end."""
    writer.begin_step(step)
    writer.write_recording(step, "burst.wav", _codes(step), 48000, meta={"burst": 1})
    writer.write_image(step, "cam0.png", _image(step))
    writer.write_json(step, "pose.json", {"step": step, "ok": True})
    writer.end_step(step)


def _run_script(path: Path) -> None:
    writer = SessionWriter.create(path, CAPTURE, session_id="crash-test")
    for step in SCRIPT_STEPS:
        _record_step(writer, step)
    writer.stop()


def _assert_step_content(reader: SessionReader, step: str) -> None:
    codes, rate = reader.read_recording(step, "burst.wav")
    assert rate == 48000
    assert codes.dtype == np.int16
    np.testing.assert_array_equal(codes, _codes(step))
    np.testing.assert_array_equal(reader.read_image(step, "cam0.png"), _image(step))
    assert reader.read_json(step, "pose.json") == {"step": step, "ok": True}


# -- round trip -----------------------------------------------------------------------------------


def test_round_trip_keeps_capture_codes_images_and_steps(tmp_path: Path) -> None:
    path = tmp_path / "session"
    capture = json.loads(json.dumps(CAPTURE))
    writer = SessionWriter.create(path, capture)
    capture["volts_per_code"] = 1.0  # the stored configuration is a frozen copy
    assert writer.capture == CAPTURE
    assert writer.begin_step("reference/4") == 1
    writer.write_recording("reference/4", "speaker_4.wav", _codes("r4", 500), 96000)
    writer.write_image("reference/4", "cam0.png", _image("r4", colour=False))
    writer.write_image("reference/4", "cam1.png", _image("r4"))
    writer.write_json("reference/4", "status.json", {"overruns": 0, "boards": ["a", "b"]})
    writer.end_step("reference/4")
    _record_step(writer, "pose/0003")
    assert writer.completed_steps() == {"reference/4": 1, "pose/0003": 1}
    writer.stop()

    reader = SessionReader(path)
    assert reader.session_id == writer.session_id
    assert reader.capture == CAPTURE
    assert reader.status == "complete"
    assert set(reader.steps()) == {"reference/4", "pose/0003"}
    step = reader.steps()["reference/4"]
    assert step.dir == "references/4-a1"
    assert set(step.files) == {"speaker_4.wav", "cam0.png", "cam1.png", "status.json"}
    assert step.files["speaker_4.wav"].meta["n_channels"] == 80
    codes, rate = reader.read_recording("reference/4", "speaker_4.wav")
    assert (codes.dtype, rate) == (np.int16, 96000)
    np.testing.assert_array_equal(codes, _codes("r4", 500))
    assert sf.info(str(path / step.files["speaker_4.wav"].path)).subtype == "PCM_16"
    np.testing.assert_array_equal(reader.read_image("reference/4", "cam0.png"), _image("r4", False))
    np.testing.assert_array_equal(reader.read_image("reference/4", "cam1.png"), _image("r4"))
    assert reader.read_json("reference/4", "status.json") == {"overruns": 0, "boards": ["a", "b"]}
    _assert_step_content(reader, "pose/0003")
    assert reader.verify() == []
    on_disk = SessionManifest.model_validate_json((path / MANIFEST_NAME).read_text())
    assert on_disk == reader.manifest()
    assert on_disk.status == "complete"
    kinds = [record.kind for record in journal_records(path)]
    assert kinds[0] == "session_start" and kinds[-1] == "session_stop"
    assert [record.seq for record in journal_records(path)] == list(range(len(kinds)))


def test_large_recordings_switch_to_rf64(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_writer, "WAV_MAX_DATA_BYTES", 0)
    writer = SessionWriter.create(tmp_path / "s", {})
    writer.begin_step("refmic")
    target = writer.write_recording("refmic", "long.wav", _codes("long", 100, 3), 48000)
    writer.end_step("refmic")
    writer.stop()
    assert sf.info(str(target)).format == "RF64"
    reader = SessionReader(tmp_path / "s")
    assert reader.steps()["refmic"].files["long.wav"].meta["container"] == "RF64"
    np.testing.assert_array_equal(
        reader.read_recording("refmic", "long.wav")[0], _codes("long", 100, 3)
    )


def test_attempt_directories_follow_the_documented_rule() -> None:
    assert attempt_dir("pose/0003", 2) == "poses/0003-a2"
    assert attempt_dir("reference/4", 1) == "references/4-a1"
    assert attempt_dir("refmic", 1) == "refmic-a1"


def test_abandoned_attempt_is_retried_in_a_new_directory(tmp_path: Path) -> None:
    writer = SessionWriter.create(tmp_path / "s", {})
    writer.begin_step("pose/0000")
    first = writer.write_recording("pose/0000", "burst.wav", _codes("bad"), 48000)
    writer.abandon_step("pose/0000", "overrun on board 2")
    first_bytes = first.read_bytes()
    assert writer.begin_step("pose/0000") == 2
    writer.write_recording("pose/0000", "burst.wav", _codes("good"), 48000)
    writer.end_step("pose/0000")
    writer.stop()
    assert first.read_bytes() == first_bytes
    reader = SessionReader(tmp_path / "s")
    assert reader.steps()["pose/0000"].attempt == 2
    np.testing.assert_array_equal(
        reader.read_recording("pose/0000", "burst.wav")[0], _codes("good")
    )


# -- crashes --------------------------------------------------------------------------------------

CRASH_SITES = ("journal", "before_rename", "after_rename", "after_mkdir")


def _hooked(site: str, on_hit: Callable[[], object]) -> tuple[object, str, Callable]:
    """(owner, attribute, replacement) that calls `on_hit` at each occurrence of `site`."""
    if site == "journal":
        append = JournalWriter.append

        def hooked_append(self: JournalWriter, record: Record) -> None:
            append(self, record)
            on_hit()

        return JournalWriter, "append", hooked_append
    original = os.rename if "rename" in site else os.mkdir
    before = site == "before_rename"

    def hooked(*args: Any, **kwargs: Any) -> None:
        if before:
            on_hit()
        original(*args, **kwargs)
        if not before:
            on_hit()

    return os, "rename" if "rename" in site else "mkdir", hooked


def _count_hits(site: str, path: Path, monkeypatch: pytest.MonkeyPatch) -> int:
    """How often `site` occurs in a full, uncrashed run of the script."""
    hits = itertools.count()
    with monkeypatch.context() as patch:
        patch.setattr(*_hooked(site, lambda: next(hits)))
        _run_script(path)
    return next(hits)


# Children come from a fork server: a fresh single-threaded process started once, so no child
# inherits pytest's threads (or their locks) as a fork of the test process itself would.
_CHILDREN = multiprocessing.get_context("forkserver")
_CHILDREN.set_forkserver_preload([__name__])  # each child starts with this module imported


def _in_child(work: Callable[[], int]) -> int:
    """Run `work` in a child process; the status it exits with (os._exit: no cleanup)."""
    child = _CHILDREN.Process(target=_exit_with, args=(work,))
    child.start()
    child.join(timeout=120)
    assert child.exitcode is not None, "the child process hung"
    return child.exitcode


def _exit_with(work: Callable[[], int]) -> None:
    code = 3
    try:
        code = work()
    except BaseException:  # the child must end in os._exit
        traceback.print_exc()
    finally:
        os._exit(code)


def _crash_script(path: Path, site: str, k: int) -> int:
    hits = itertools.count(1)

    def crash() -> None:
        if next(hits) == k:
            os._exit(CRASHED)

    setattr(*_hooked(site, crash))
    _run_script(path)
    return 0


def _run_script_crashing(path: Path, site: str, k: int) -> int:
    """Run the script in a child that dies at the k-th hit of `site`; its exit code."""
    return _in_child(functools.partial(_crash_script, path, site, k))


def _file_hashes(path: Path) -> dict[str, str]:
    """sha256 of every finished file of the session except the journal and manifest."""
    return {
        file.relative_to(path).as_posix(): hashlib.sha256(file.read_bytes()).hexdigest()
        for file in path.rglob("*")
        if file.is_file()
        and file.name not in (JOURNAL_NAME, MANIFEST_NAME)
        and not file.name.endswith(".partial")
    }


def _started(path: Path) -> bool:
    """Whether the session got as far as its first journal record."""
    if not (path / JOURNAL_NAME).exists():
        return False
    return bool(scan_journal(path / JOURNAL_NAME).records)


def _resume_finish_and_check(path: Path) -> None:
    """Recover a crashed scripted session as an operator would, then check it thoroughly."""
    before = _file_hashes(path)
    journal_before = (path / JOURNAL_NAME).read_bytes() if _started(path) else b""
    writer: SessionWriter | None = None
    if not _started(path):  # died inside create: the directory may be reused
        with pytest.raises(SessionError, match=r"SessionWriter\.create"):
            SessionReader(path)
        writer = SessionWriter.create(path, CAPTURE, session_id="crash-test")
    elif SessionReader(path).status == "complete":  # the crash came after session_stop
        with pytest.raises(SessionError, match=r"is closed.*start a new session"):
            SessionWriter.resume(path)
    else:
        assert SessionReader(path).status == "interrupted"
        writer = SessionWriter.resume(path)
    if writer is not None:
        for step in SCRIPT_STEPS:
            if step not in writer.completed_steps():
                _record_step(writer, step)
        writer.stop()

    reader = SessionReader(path)
    assert reader.status == "complete"
    assert reader.verify() == []
    assert set(reader.steps()) == set(SCRIPT_STEPS)
    step_ends = Counter(r.step for r in journal_records(path) if isinstance(r, StepEnd))
    assert step_ends == Counter(SCRIPT_STEPS)
    for step in SCRIPT_STEPS:
        assert set(reader.steps()[step].files) == {"burst.wav", "cam0.png", "pose.json"}
        _assert_step_content(reader, step)
    after = _file_hashes(path)
    changed = sorted(name for name, digest in before.items() if after.get(name) != digest)
    assert changed == [], f"files changed or lost by the recovery: {changed}"
    assert (path / JOURNAL_NAME).read_bytes().startswith(journal_before)
    assert list(path.rglob("*.partial")) == []
    on_disk = SessionManifest.model_validate_json((path / MANIFEST_NAME).read_text())
    assert on_disk == reader.manifest()


@pytest.mark.parametrize("site", CRASH_SITES)
@pytest.mark.slow
def test_resume_after_a_crash_at_every_point(
    site: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    n_hits = _count_hits(site, tmp_path / "count", monkeypatch)
    assert n_hits >= 4
    for k in range(1, n_hits + 1):
        path = tmp_path / f"crash-{k}"
        assert _run_script_crashing(path, site, k) == CRASHED, f"{site} #{k}: child did not crash"
        try:
            _resume_finish_and_check(path)
        except (AssertionError, SessionError) as exc:
            raise AssertionError(f"crash at {site} #{k} of {n_hits}: {exc}") from exc


@pytest.mark.parametrize(
    "tail",
    [b'{"seq": 8, "time_utc": "2026-', b"\x00\x00\x00\x00", b'{"seq": 8}'],
    ids=["cut-mid-line", "zero-fill", "invalid-without-newline"],
)
def test_a_torn_last_journal_line_is_ignored_and_dropped_on_resume(
    tmp_path: Path, tail: bytes
) -> None:
    path = tmp_path / "s"
    writer = SessionWriter.create(path, CAPTURE)
    _record_step(writer, SCRIPT_STEPS[0])
    writer.begin_step(SCRIPT_STEPS[1])
    writer.close()  # as a crash would leave it, minus the crash
    n_records = len(journal_records(path))
    with (path / JOURNAL_NAME).open("ab") as fh:
        fh.write(tail)

    reader = SessionReader(path)
    assert reader.status == "interrupted"
    assert set(reader.steps()) == {SCRIPT_STEPS[0]}
    assert len(journal_records(path)) == n_records
    writer = SessionWriter.resume(path)
    assert scan_journal(path / JOURNAL_NAME).torn_tail is False
    _record_step(writer, SCRIPT_STEPS[1])
    writer.stop()
    reader = SessionReader(path)
    assert reader.status == "complete"
    assert reader.steps()[SCRIPT_STEPS[1]].attempt == 2
    assert reader.verify() == []


def test_a_corrupt_line_before_the_end_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "s"
    writer = SessionWriter.create(path, CAPTURE)
    _record_step(writer, "refmic")
    writer.close()
    lines = (path / JOURNAL_NAME).read_bytes().split(b"\n")
    lines[2] = lines[2][:20]
    (path / JOURNAL_NAME).write_bytes(b"\n".join(lines))
    with pytest.raises(SessionError, match=r"line 3: not a valid journal record.*do not resume"):
        SessionReader(path)
    with pytest.raises(SessionError, match="line 3"):
        SessionWriter.resume(path)


def test_a_journal_with_a_missing_record_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "s"
    writer = SessionWriter.create(path, CAPTURE)
    _record_step(writer, "refmic")
    writer.close()
    lines = (path / JOURNAL_NAME).read_bytes().splitlines(keepends=True)
    (path / JOURNAL_NAME).write_bytes(b"".join(lines[:1] + lines[2:]))  # drop step_begin
    with pytest.raises(SessionError, match=r"journal.jsonl: record seq 2 \(file\): expected seq 1"):
        SessionReader(path)


# -- refusals -------------------------------------------------------------------------------------


@pytest.fixture
def open_writer(tmp_path: Path) -> SessionWriter:
    """A session with step "refmic" completed and attempt 1 of "pose/0000" open."""
    writer = SessionWriter.create(tmp_path / "s", CAPTURE)
    _record_step(writer, "refmic")
    writer.begin_step("pose/0000")
    return writer


def test_create_refuses_an_existing_session_or_a_non_empty_directory(tmp_path: Path) -> None:
    SessionWriter.create(tmp_path / "s", CAPTURE).stop()
    with pytest.raises(SessionError, match=r"already holds a session; use SessionWriter\.resume"):
        SessionWriter.create(tmp_path / "s", CAPTURE)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("x")
    with pytest.raises(SessionError, match="is not empty"):
        SessionWriter.create(tmp_path / "other", CAPTURE)
    SessionWriter.create(tmp_path / "empty-ok", CAPTURE).stop()


@pytest.mark.parametrize("journal", [b"", b'{"seq": 0, "time_utc": "20'])
def test_a_directory_whose_create_was_cut_short_can_be_created_again(
    tmp_path: Path, journal: bytes
) -> None:
    path = tmp_path / "s"
    path.mkdir()
    (path / JOURNAL_NAME).write_bytes(journal)
    with pytest.raises(SessionError, match=r"creation was interrupted.*SessionWriter\.create"):
        SessionReader(path)
    with pytest.raises(SessionError, match="creation was interrupted"):
        SessionWriter.resume(path)
    SessionWriter.create(path, CAPTURE).stop()
    assert SessionReader(path).status == "complete"


@pytest.mark.parametrize(
    ("action", "message"),
    [
        (
            lambda w: w.write_json("pose/9999", "x.json", {}),
            r"'pose/9999' has no open attempt.*begin_step",
        ),
        (lambda w: w.write_json("refmic", "x.json", {}), "'refmic' is already completed"),
        (lambda w: w.begin_step("refmic"), "'refmic' is already completed"),
        (lambda w: w.begin_step("pose/0001"), "'pose/0000' attempt 1 is still open"),
        (lambda w: w.begin_step("../escape"), "invalid step id"),
        (lambda w: w.end_step("pose/0001"), "'pose/0001' has no open attempt"),
        (
            lambda w: w.write_recording("pose/0000", "a.wav", np.zeros((10, 2)), 48000),
            "must be a numpy int16 array.*got float64",
        ),
        (
            lambda w: w.write_recording("pose/0000", "a.wav", np.zeros(10, np.int16), 48000),
            r"shape \(n_samples, n_channels\), got shape \(10,\)",
        ),
        (
            lambda w: w.write_recording(
                "pose/0000", "a.wav", np.zeros((10, 1025), np.int16), 48000
            ),
            "1 to 1024 channels",
        ),
        (
            lambda w: w.write_recording("pose/0000", "a.wav", np.zeros((10, 2), np.int16), 48000.5),
            "sample_rate_hz must be a positive integer",
        ),
        (
            lambda w: w.write_recording("pose/0000", "sub/a.wav", np.zeros((10, 2), np.int16), 1),
            "invalid file name 'sub/a.wav'",
        ),
        (lambda w: w.write_image("pose/0000", "cam0.png", np.zeros((4, 4), np.float32)), "uint8"),
        (lambda w: w.write_image("pose/0000", "cam0.jpg", np.zeros((4, 4), np.uint8)), "'.png'"),
        (
            lambda w: w.write_json("pose/0000", "x.json", {"v": np.int64(3)}),
            "JSON-serialisable",
        ),
        (
            lambda w: w.write_json("pose/0000", "x.json", {"v": float("nan")}),
            "without NaN",
        ),
        (
            lambda w: w.write_image("pose/0000", "c.png", np.zeros((4, 4), np.uint8), {"width": 1}),
            r"may not set \['width'\]",
        ),
        (lambda w: w.stop(), "'pose/0000' attempt 1 is still open; end_step it first"),
        (lambda w: w.stop("crashed"), "exit_status must be one of"),
    ],
)
def test_bad_calls_are_refused_with_a_clear_message(
    open_writer: SessionWriter, action: Callable[[SessionWriter], object], message: str
) -> None:
    with pytest.raises(SessionError, match=message):
        action(open_writer)
    assert list(open_writer.path.rglob("*.partial")) == []


def test_a_name_is_written_once_per_attempt(open_writer: SessionWriter) -> None:
    open_writer.write_json("pose/0000", "pose.json", {"a": 1})
    with pytest.raises(SessionError, match=r"pose\.json was already written in this attempt"):
        open_writer.write_json("pose/0000", "pose.json", {"a": 2})
    target = open_writer.path / "poses" / "0000-a1" / "cam0.png"
    target.write_bytes(b"not ours")
    with pytest.raises(SessionError, match=r"cam0\.png already exists"):
        open_writer.write_image("pose/0000", "cam0.png", _image("x"))
    assert target.read_bytes() == b"not ours"


def test_a_failed_write_leaves_no_file_and_no_record(
    open_writer: SessionWriter, monkeypatch: pytest.MonkeyPatch
) -> None:
    def full_disk(*args: object, **kwargs: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_writer.sf, "write", full_disk)
    n_records = len(journal_records(open_writer.path))
    with pytest.raises(
        SessionError, match=r"cannot write .*burst.wav.*No space left.*capture step pose/0000"
    ):
        open_writer.write_recording("pose/0000", "burst.wav", _codes("x"), 48000)
    assert list((open_writer.path / "poses" / "0000-a1").iterdir()) == []
    assert len(journal_records(open_writer.path)) == n_records


def test_stop_other_than_success_abandons_the_open_attempt(open_writer: SessionWriter) -> None:
    open_writer.stop("aborted", "operator pressed stop")
    reader = SessionReader(open_writer.path)
    assert reader.status == "aborted"
    assert set(reader.steps()) == {"refmic"}
    assert journal_records(open_writer.path)[-2].kind == "step_abandoned"
    with pytest.raises(SessionError, match="is closed"):
        open_writer.begin_step("pose/0001")
    with pytest.raises(SessionError, match=r"is closed.*start a new session"):
        SessionWriter.resume(open_writer.path)


def _resume_elsewhere(path: Path) -> int:
    try:
        SessionWriter.resume(path)
        return 0
    except SessionError as exc:
        return 10 if "locked by another process" in str(exc) else 11


def test_another_process_cannot_write_an_open_session(open_writer: SessionWriter) -> None:
    assert _in_child(functools.partial(_resume_elsewhere, open_writer.path)) == 10
    open_writer.write_json("pose/0000", "still-mine.json", {})


def test_a_resume_in_the_same_process_supersedes_the_earlier_writer(
    open_writer: SessionWriter,
) -> None:
    resumed = SessionWriter.resume(open_writer.path)
    with pytest.raises(SessionError, match="superseded by a newer SessionWriter"):
        open_writer.begin_step("pose/0001")
    assert resumed.begin_step("pose/0000") == 2
    resumed.stop("failed", "test")
    assert SessionReader(open_writer.path).status == "failed"


def test_reader_refuses_what_is_not_a_session(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="is not a directory"):
        SessionReader(tmp_path / "nowhere")
    with pytest.raises(SessionError, match=r"is not a micam session: it has no journal\.jsonl"):
        SessionReader(tmp_path)
    with pytest.raises(SessionError, match="is not a micam session"):
        SessionWriter.resume(tmp_path)


def test_reader_refuses_unknown_steps_and_files(open_writer: SessionWriter) -> None:
    reader = SessionReader(open_writer.path)
    with pytest.raises(SessionError, match=r"no completed step 'pose/0000'.*\['refmic'\]"):
        reader.read_recording("pose/0000", "burst.wav")
    with pytest.raises(SessionError, match=r"has no file 'nope\.wav'"):
        reader.read_recording("refmic", "nope.wav")
    with pytest.raises(SessionError, match="holds role 'image', not 'recording'"):
        reader.read_recording("refmic", "cam0.png")


def test_verify_reports_a_flipped_byte_and_a_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "s"
    _run_script(path)
    recording = path / attempt_dir("refmic", 1) / "burst.wav"
    data = bytearray(recording.read_bytes())
    data[len(data) // 2] ^= 0x01
    recording.write_bytes(bytes(data))
    (path / attempt_dir("pose/0000", 1) / "cam0.png").unlink()
    problems = SessionReader(path).verify()
    assert len(problems) == 2
    assert problems[0].startswith("refmic-a1/burst.wav (step 'refmic'): checksum mismatch")
    assert problems[1] == "poses/0000-a1/cam0.png (step 'pose/0000'): missing"
