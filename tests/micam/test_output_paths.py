"""Every output option is checked before the work: a dangling symbolic link, a file where a
directory goes (or the reverse) or a parent that is a file ends in one line naming the option
(exit 2), never in "a bug" and never in a file written through the link."""

from __future__ import annotations

from pathlib import Path

import pytest

from micam.cli import main

# (the command line with OUT where the output goes, the option, a directory output?)
COMMANDS = [
    (["simulate", "--out", "OUT", "--poses", "1", "--quiet"], "--out", True),
    (["import", "SPEC", "--out", "OUT"], "--out", True),
    (["import", "SPEC", "--out", "OUT", "--check"], "--out", True),
    (["study", "--out", "OUT"], "--out", True),
    (["calibrate", "SESSION", "--out", "OUT"], "--out", False),
    (["calibrate", "SESSION", "--out", "r.json", "--acoular-xml", "OUT"], "--acoular-xml", False),
    (["calibrate", "SESSION", "--out", "r.json", "--acoular-calib", "OUT"], "--acoular-calib",
     False),
    (["calibrate", "SESSION", "--out", "r.json", "--report", "OUT"], "--report", True),
    (["image", "SESSION", "--geometry", "g.json", "--pose", "0", "--speaker", "0", "--band",
      "4000", "--out", "OUT"], "--out", False),
    (["evaluate-imaging", "SESSION", "--folds", "2", "--json", "OUT"], "--json", False),
    (["live", "video", "--geometry", "g.json", "--recording", "rec", "--out", "OUT"], "--out",
     False),
    (["config", "template", "import", "--out", "OUT"], "--out", False),
]


def _ids(command: tuple) -> str:
    return " ".join(w for w in command[0] if w.isalpha() or w.startswith("--"))


def _run(tmp_path: Path, argv: list[str], out: Path) -> int:
    names = {"OUT": str(out), "SPEC": str(tmp_path / "import.toml"),
             "SESSION": str(tmp_path / "session")}
    return main([names.get(word, word) for word in argv])


@pytest.mark.parametrize(("argv", "flag", "directory"), COMMANDS, ids=map(_ids, COMMANDS))
@pytest.mark.parametrize("kind", ["dangling link", "wrong kind", "parent is a file"])
def test_an_unusable_output_is_named_before_any_work(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture,
        argv: list[str], flag: str, directory: bool, kind: str) -> None:
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out"
    if kind == "dangling link":
        out.symlink_to(tmp_path / "elsewhere")
        words = "is a symbolic link to"
    elif kind == "wrong kind":
        (out.write_text("x") if directory else out.mkdir())
        words = "is a file, not a directory" if directory else "is a directory"
    else:
        (tmp_path / "file").write_text("x")
        out = tmp_path / "file" / "out"
        words = "not a directory"
    assert _run(tmp_path, argv, out) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("micam: error: ") and flag in err and words in err, err
    assert not (tmp_path / "elsewhere").exists()
