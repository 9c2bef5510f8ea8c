"""Damaged sessions: every file is checked against the journal before it is read, and what is
wrong is one clear line naming the file, never a traceback and never a calibration of damaged
data (`micam calibrate`, `micam inspect`, the session reader)."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

from micam.cli import main
from acquisition.contracts.session import SessionError, SessionReader


@pytest.fixture
def session(small_session: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "s"
    shutil.copytree(small_session, copy)
    return copy


def _file(session: Path, step: str, name: str) -> Path:
    return session / SessionReader(session).steps()[step].files[name].path


def _rejournal(session: Path, path: Path) -> None:
    """Make the journal agree with `path` as it is now (what a careful vandal would do)."""
    data = path.read_bytes()
    relative = str(path.relative_to(session))
    journal = session / "journal.jsonl"
    lines = []
    for line in journal.read_text().splitlines():
        record = json.loads(line)
        if record.get("kind") == "file" and record["path"] == relative:
            record.update(sha256=hashlib.sha256(data).hexdigest(), bytes=len(data))
        lines.append(json.dumps(record))
    journal.write_text("\n".join(lines) + "\n")


def _flip(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


DAMAGE = {
    "flipped byte": (_flip, "checksum mismatch"),
    "truncated": (_truncate, "checksum mismatch"),
    "garbage": (lambda p: p.write_bytes(b"\x89PNG not really" * 10), "checksum mismatch"),
    "empty": (lambda p: p.write_bytes(b""), "checksum mismatch"),
    "missing": (lambda p: p.unlink(), "missing"),
}


def _calibrate(session: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> str:
    out = tmp_path / "result.json"
    assert main(["calibrate", str(session), "--out", str(out), "--no-joint"]) == 2
    assert not out.exists()
    err = capsys.readouterr().err
    last = err.rstrip().splitlines()[-1]  # after the progress bar
    assert last.startswith("micam: error: ") and "Traceback" not in err, err
    return last


@pytest.mark.parametrize(("step", "name"), [("pose/0001", "cam0.png"),
                                            ("reference/2", "speaker_2.wav")])
@pytest.mark.parametrize("damage", sorted(DAMAGE))
def test_calibrate_names_the_damaged_file(session: Path, tmp_path: Path, step: str, name: str,
                                          damage: str, capsys: pytest.CaptureFixture) -> None:
    path = _file(session, step, name)
    spoil, words = DAMAGE[damage]
    spoil(path)
    err = _calibrate(session, tmp_path, capsys)
    assert f"{path.relative_to(session)} (step '{step}'): {words}" in err


@pytest.mark.parametrize(("step", "name", "spoil", "words"), [
    ("pose/0000", "cam0.png", DAMAGE["garbage"][0], "not readable as a PNG image"),
    ("pose/0000", "cam0.png", DAMAGE["empty"][0], "not readable as a PNG image"),
    ("reference/1", "speaker_1.wav", _truncate, "speaker_1.wav"),
    ("reference/1", "speaker_1.wav", DAMAGE["empty"][0], "not readable as a WAV recording"),
])
def test_a_file_that_matches_an_edited_journal_is_still_refused_clearly(
        session: Path, tmp_path: Path, step: str, name: str, spoil, words: str,
        capsys: pytest.CaptureFixture) -> None:
    path = _file(session, step, name)
    spoil(path)
    _rejournal(session, path)
    err = _calibrate(session, tmp_path, capsys)
    assert str(path) in err and words in err


def test_the_reader_checks_before_it_decodes(session: Path) -> None:
    path = _file(session, "pose/0000", "speaker_0.wav")
    _flip(path)
    with pytest.raises(SessionError, match=r"checksum mismatch.*journal recorded.*damaged"):
        SessionReader(session).read_recording("pose/0000", "speaker_0.wav")


def test_inspect_explains_an_edited_capture_configuration(
        session: Path, capsys: pytest.CaptureFixture) -> None:
    journal = session / "journal.jsonl"
    first, *rest = journal.read_text().splitlines()
    start = json.loads(first)
    del start["capture"]["columns"]
    journal.write_text("\n".join([json.dumps(start), *rest]) + "\n")
    assert main(["inspect", str(session)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("micam: error: ") and "\n" not in err and "columns" in err, err


def test_inspect_reports_damage_without_a_traceback(session: Path,
                                                    capsys: pytest.CaptureFixture) -> None:
    _flip(_file(session, "pose/0001", "speaker_3.wav"))
    (session / "truth.json").write_text("{not json")
    assert main(["inspect", str(session)]) == 1
    out = capsys.readouterr().out
    assert "1 problems" in out and "speaker_3.wav" in out and "not readable" in out
