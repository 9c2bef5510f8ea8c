"""Damaged sessions: every file is checked against the journal before it is read, and what is
wrong is one clear line naming the file, never a traceback and never a calibration of damaged
data (`micam calibrate`, `micam inspect`, the session reader)."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pytest

from acquisition.contracts.session import SessionError, SessionReader
from micam.cli import main
from tests.peak_memory import blank_png, peak_growth


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
    "truncated": (_truncate, "size mismatch"),  # refused before it is read
    "garbage": (lambda p: p.write_bytes(b"\x89PNG not really" * 10), "size mismatch"),
    "empty": (lambda p: p.write_bytes(b""), "size mismatch"),
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
@pytest.mark.slow
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


# ---------------------------------------------------------------------------------------------
# Sizes from an untrusted session are bounded before they cost memory


def _refusal_in_fresh_process(session: Path, call: str) -> tuple[int, str]:
    """The peak memory growth, bytes, of `SessionReader(session)` followed by `call` (on the
    reader `r`) in a new interpreter, and the SessionError's message it printed."""
    grown, done = peak_growth(
        "from acquisition.contracts.session import SessionError, SessionReader",
        f"""
        try:
            r = SessionReader(Path({str(session)!r}))
            {call}
        except SessionError as exc:
            print(exc)
        """)
    return grown, done.stdout + done.stderr


@pytest.mark.slow
def test_a_huge_png_that_matches_the_journal_is_refused_before_decoding(
        session: Path, tmp_path: Path) -> None:
    """A 16000 x 16000 PNG of one colour is 250 kB on disk and 256 MB decoded: with the journal
    edited to its size and checksum, the reader refuses it from its header."""
    path = _file(session, "pose/0000", "cam0.png")
    path.write_bytes(blank_png(16000, 16000))
    _rejournal(session, path)
    grown, said = _refusal_in_fresh_process(session, 'r.read_image("pose/0000", "cam0.png")')
    assert "its header states more than the 100000000 pixels micam decodes" in said, said
    assert grown < 64 * 2**20, f"reading it grew the peak memory by {grown / 2**20:.0f} MiB"


def test_a_compressed_recording_that_matches_the_journal_is_refused_before_decoding(
        session: Path, tmp_path: Path) -> None:
    """A FLAC of silence in place of a WAV: small on disk, large decoded; the header says it
    is not what the session store writes, and nothing is decoded."""
    import numpy as np
    import soundfile as sf

    path = _file(session, "reference/1", "speaker_1.wav")
    with sf.SoundFile(path, "w", 8000, 2, format="FLAC", subtype="PCM_16") as f:
        block = np.zeros((2**20, 2), dtype=np.int16)
        for _ in range(40):  # 42 million frames: 168 MB of codes decoded
            f.write(block)
    _rejournal(session, path)
    grown, said = _refusal_in_fresh_process(session,
                                            'r.read_recording("reference/1", "speaker_1.wav")')
    assert "it is FLAC PCM_16, the session store writes 16-bit PCM WAV" in said, said
    assert grown < 64 * 2**20, f"reading it grew the peak memory by {grown / 2**20:.0f} MiB"


# ---------------------------------------------------------------------------------------------
# The journal: only a genuinely torn last line is forgiven, and lines are bounded as read


def _journal(session: Path) -> Path:
    return session / "journal.jsonl"


@pytest.mark.parametrize(("tail", "words"), [
    (b"garbage{", "line 51: it follows session_stop"),  # no newline: a torn tail, but stopped
    (b'{"seq": 50}\n', "line 51: it follows session_stop"),
    (b"\x00" * 64, "line 51: it follows session_stop"),
])
def test_anything_after_session_stop_is_damage_naming_its_line(
        session: Path, tmp_path: Path, tail: bytes, words: str,
        capsys: pytest.CaptureFixture) -> None:
    with _journal(session).open("ab") as fh:
        fh.write(tail)
    err = _calibrate(session, tmp_path, capsys)
    assert words in err and "do not resume it" in err, err


def test_an_invalid_last_line_with_its_newline_is_damage(session: Path) -> None:
    """A crash cuts the last line short; a whole line (newline and all) that is no record
    was written by something else."""
    lines = _journal(session).read_bytes().splitlines(keepends=True)
    lines[-1] = b'{"seq": 49, "kind": "session_stop"}\n'
    _journal(session).write_bytes(b"".join(lines))
    with pytest.raises(SessionError, match=r"line 50: not a valid journal record"):
        SessionReader(session)


def test_a_200_mb_line_is_refused_without_being_read(session: Path) -> None:
    with _journal(session).open("ab") as fh:
        for _ in range(200):
            fh.write(b"x" * 2**20)
        fh.write(b"\n")
    grown, said = _refusal_in_fresh_process(session, "pass")
    assert "line 51: longer than 1048576 bytes" in said, said
    assert grown < 16 * 2**20, f"reading it grew the peak memory by {grown / 2**20:.0f} MiB"


def test_a_journal_beyond_its_bound_is_refused_by_its_size(session: Path) -> None:
    from acquisition.contracts.session._journal import MAX_JOURNAL_BYTES

    with _journal(session).open("ab") as fh:
        fh.truncate(MAX_JOURNAL_BYTES + 1)  # sparse: no disk space used
    with pytest.raises(SessionError, match=f"more than the {MAX_JOURNAL_BYTES} a journal may "
                                           "hold"):
        SessionReader(session)


def test_the_writer_refuses_a_record_readers_would_refuse(tmp_path: Path) -> None:
    from acquisition.contracts.session import SessionWriter

    with pytest.raises(SessionError, match="longer than the 1048576 a journal line may hold"):
        SessionWriter.create(tmp_path / "s", capture={"note": "x" * 2**20})
    SessionWriter.create(tmp_path / "s", capture={"note": "fits"}).stop()  # the path is reusable
