"""Every file an option names is parsed with its errors turned into one line naming the option,
the file and what is wrong (exit 2): --intrinsics, --prior (JSON and Acoular XML), --truth
and --geometry of `micam calibrate`, `micam image`, `micam live video` and `micam
evaluate-imaging`. A file too large for its kind, a FIFO or a directory is refused before
anything is read. The loaders behind them are fuzzed with random documents."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from micam.cli import main

LONG = os.environ.get("MICAM_LONG_TESTS") == "1"
EXAMPLES = int(os.environ.get("MICAM_FUZZ_EXAMPLES", "5000" if LONG else "150"))

# (the command line, FILE where the file goes, the option named in the error)
OPTIONS = {
    "calibrate --intrinsics": (["calibrate", "SESSION", "--out", "r.json", "--no-joint",
                                "--intrinsics", "cam0=FILE"], "--intrinsics"),
    "calibrate --prior json": (["calibrate", "SESSION", "--out", "r.json", "--no-joint",
                                "--prior", "FILE"], "--prior"),
    "calibrate --prior xml": (["calibrate", "SESSION", "--out", "r.json", "--no-joint",
                               "--prior", "FILE.xml"], "--prior"),
    "calibrate --truth": (["calibrate", "SESSION", "--out", "r.json", "--no-joint",
                           "--truth", "FILE"], "--truth"),
    "image --geometry": (["image", "SESSION", "--geometry", "FILE", "--pose", "0", "--speaker",
                          "0", "--band", "4000", "--out", "m.png"], "--geometry"),
    "live video --geometry": (["live", "video", "--geometry", "FILE", "--recording", "rec",
                               "--out", "v.avi"], "--geometry"),
    "evaluate-imaging --geometry": (["evaluate-imaging", "SESSION", "--geometry", "FILE",
                                     "--quiet"], "--geometry"),
    "evaluate-imaging --truth": (["evaluate-imaging", "SESSION", "--folds", "2", "--truth",
                                  "FILE", "--quiet"], "--truth"),
}

DEEP = "[" * 100_000 + "]" * 100_000
CONTENTS = {
    "not JSON": "notjson",
    "cut short": '{"microphones": [',
    "deeply nested": DEEP,
    "empty object": "{}",
    "a list": "[1, 2]",
    "wrong types": json.dumps({"microphones": [{"id": "x", "position_m": "y"}],
                               "speed_of_sound_m_s": [], "cameras": {"a": 1}, "K": None}),
    "not a number": '{"microphones": [{"id": 0, "position_m": [NaN, 0, 0]}],'
                    ' "speed_of_sound_m_s": 343, "cameras": [{"name": "cam0", "K": [[1]]}]}',
    "ragged": json.dumps({"microphones": [{"id": 0, "position_m": [[1, 2], [3]]}],
                          "speed_of_sound_m_s": 343, "cameras": []}),
    "bad XML": "<MicArray><pos Name='Point 0' x='1' y='2' z=",
    "not UTF-8": "\udcff",
}


@pytest.fixture(scope="module")
def session(small_session: Path) -> Path:
    return small_session


def _run(tmp_path: Path, argv: list[str], file: Path, session: Path) -> int:
    def word(w: str) -> str:
        if w == "SESSION":
            return str(session)
        return w.partition("=")[0] + "=" + str(file) if "=FILE" in w else (
            str(file) if "FILE" in w else w)

    return main([word(w) for w in argv])


def _option(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, option: str
            ) -> tuple[list[str], str, Path]:
    """The command line of `option`, its flag and where its file goes (the test runs in
    `tmp_path`)."""
    monkeypatch.chdir(tmp_path)
    argv, flag = OPTIONS[option]
    name = next(w for w in argv if "FILE" in w).split("=")[-1]
    return argv, flag, tmp_path / name.replace("FILE", "option-file")


def _assert_named(err: str, flag: str, file: Path) -> None:
    line = err.strip().splitlines()[-1]
    assert line.startswith("micam: error: ") and "Traceback" not in err, err
    assert flag in line and file.name in line, line


@pytest.mark.parametrize("option", sorted(OPTIONS))
@pytest.mark.parametrize("content", sorted(CONTENTS))
@pytest.mark.slow
def test_a_malformed_option_file_names_the_option_and_the_file(
        tmp_path: Path, session: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture, option: str, content: str) -> None:
    argv, flag, file = _option(tmp_path, monkeypatch, option)
    file.write_text(CONTENTS[content], errors="surrogateescape")
    assert _run(tmp_path, argv, file, session) == 2
    _assert_named(capsys.readouterr().err, flag, file)


@pytest.mark.parametrize("option", sorted(OPTIONS))
@pytest.mark.parametrize("kind", ["too large", "fifo", "directory"])
def test_an_option_file_is_refused_before_it_is_read(
        tmp_path: Path, session: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture, option: str, kind: str) -> None:
    argv, flag, file = _option(tmp_path, monkeypatch, option)
    if kind == "too large":
        with file.open("wb") as fh:
            fh.truncate(2**31)  # sparse: 2 GiB that take no disk space and are never read
        words = "larger than"
    elif kind == "fifo":
        os.mkfifo(file)  # reading it would wait forever
        words = "not a file"
    else:
        file.mkdir()
        words = "not a file"
    assert _run(tmp_path, argv, file, session) == 2
    err = capsys.readouterr().err
    _assert_named(err, flag, file)
    assert words in err.replace("not a regular file", "not a file"), err


# ---------------------------------------------------------------------------------------------
# The loaders, fuzzed with random documents: only their own input error, never another


def _documents() -> st.SearchStrategy:
    scalars = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5)
    values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4)
                          | st.dictionaries(st.text(max_size=5), inner, max_size=4), max_leaves=12)
    keys = st.sampled_from(["microphones", "speed_of_sound_m_s", "cameras", "poses", "id",
                            "position_m", "name", "K", "dist", "width", "height", "from_cam0",
                            "rotvec", "t_m", "latency_s", "board_latencies_s", "board",
                            "delay_s", "intrinsics_std", "index", "rig_to_cam0", "speakers_m",
                            "microphone_responses"])
    shaped = st.recursive(values, lambda inner: st.dictionaries(keys, inner, max_size=6)
                          | st.lists(inner, max_size=3), max_leaves=25)
    return st.dictionaries(keys, shaped, max_size=6)


@pytest.mark.timeout(4 * 3600 if LONG else 300)
@settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=not LONG,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(document=_documents())
@pytest.mark.slow
def test_the_option_file_loaders_raise_only_their_input_error(tmp_path: Path,
                                                              document: dict) -> None:
    import numpy as np

    from acquisition.intrinsics_file import IntrinsicsFileError, read_intrinsics
    from calibration.result import PriorFileError, load_prior_positions
    from calibration.truth import TruthError, load_truth
    from imaging import load_geometry
    from imaging.geometry import GeometryFileError

    path = tmp_path / "doc.json"
    path.write_text(json.dumps(document))
    for load, error in ((lambda: read_intrinsics(path, "cam0", (64, 48), "fixed"),
                         IntrinsicsFileError),
                        (lambda: load_prior_positions(path, np.array([0, 1])), PriorFileError),
                        (lambda: load_truth(path, [0, 1], ["cam0"]), TruthError),
                        (lambda: load_geometry(path), GeometryFileError)):
        try:
            load()
        except error:
            pass
