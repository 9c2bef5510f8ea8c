"""`micam import`: sessions from plain folders, every file format it reads, and refusals that
name the TOML field, what is wrong and what to write (nothing is written then)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import soundfile as sf

from acquisition.contracts.session import SessionReader
from acquisition.importer import ImportSpecError, import_session, prepare
from acquisition.intrinsics_file import IntrinsicsFileError, read_intrinsics
from micam.cli import main
from tests.peak_memory import blank_png, peak_growth

FS = 8000
N = 4 + 63 + 5  # silence before, MLS order 6, silence after
W, H = 64, 48

TOML = """sample_rate_hz = 8000
[rig]
corners_x = 6
corners_y = 9
square_m = 0.03
speakers_m = [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]]
[[channels]]
group = "rme"
columns = [1, 2]
mic_ids = [10, 11]
[reference]
group = "rme"
reference_recordings_column = 0
[burst]
silence_before_samples = 4
mls_order = 6
silence_after_samples = 5
[[cameras]]
name = "cam0"
width = 64
height = 48
[recordings]
references = ["ref0.wav", "ref1.wav"]
[[recordings.poses]]
bursts = ["p0s0.wav", "p0s1.wav"]
images = { cam0 = "p0.png" }
"""


def _folder(tmp_path: Path, toml: str = TOML) -> Path:
    """A tiny recorder folder: 16-bit WAVs of 3 columns, one image."""
    rng = np.random.default_rng(0)
    for name in ("ref0", "ref1", "p0s0", "p0s1"):
        sf.write(tmp_path / f"{name}.wav", rng.integers(-3000, 3000, (N, 3), dtype=np.int16), FS,
                 subtype="PCM_16")
    cv2.imwrite(str(tmp_path / "p0.png"), rng.integers(0, 255, (H, W), dtype=np.uint8))
    spec = tmp_path / "import.toml"
    spec.write_text(toml)
    return spec


def test_a_plain_folder_becomes_a_verified_session(tmp_path: Path) -> None:
    spec = _folder(tmp_path)
    out = tmp_path / "session"
    assert main(["import", str(spec), "--out", str(out)]) == 0
    reader = SessionReader(out)
    assert reader.status == "complete" and reader.verify() == []
    assert set(reader.steps()) == {"reference/0", "reference/1", "pose/0000", "import"}
    codes, rate = reader.read_recording("pose/0000", "speaker_1.wav")
    original, _ = sf.read(tmp_path / "p0s1.wav", dtype="int16", always_2d=True)
    assert rate == FS and np.array_equal(codes, original)  # 16-bit: bit for bit
    meta = reader.steps()["pose/0000"].files["speaker_1.wav"].meta
    assert meta["import_scale"] is None and meta["source"] == "p0s1.wav"
    image = cv2.imread(str(tmp_path / "p0.png"), cv2.IMREAD_UNCHANGED)
    assert image is not None
    assert np.array_equal(reader.read_image("pose/0000", "cam0.png"), image)
    record = reader.read_json("import", "import.json")
    assert record["description_toml"] == spec.read_text()
    assert set(record["sources_sha256"]) == {"ref0.wav", "ref1.wav", "p0s0.wav", "p0s1.wav",
                                             "p0.png"}
    assert reader.capture["kind"] == "rig-and-array"
    assert reader.capture["channels"] == [{"group": "rme", "columns": [1, 2],
                                           "mic_ids": [10, 11], "volts_per_unit": None}]


def test_other_sample_formats_are_scaled_per_column(tmp_path: Path) -> None:
    spec = _folder(tmp_path, TOML.replace('"p0s1.wav"', '"p0s1.flac"'))
    t = np.arange(N) / FS
    x = np.stack([0.5 * np.sin(2e3 * t), 0.01 * np.cos(3e3 * t), np.zeros(N)], axis=1)
    sf.write(tmp_path / "p0s1.flac", x, FS, subtype="PCM_24")
    import_session(spec, tmp_path / "s")
    reader = SessionReader(tmp_path / "s")
    codes, _ = reader.read_recording("pose/0000", "speaker_1.wav")
    scale = reader.steps()["pose/0000"].files["speaker_1.wav"].meta["import_scale"]
    assert np.abs(codes[:, :2]).max(axis=0).tolist() == [32767, 32767]  # each to full scale
    source, _ = sf.read(tmp_path / "p0s1.flac", always_2d=True)
    assert np.abs(codes[:, :2] / np.array(scale[:2]) - source[:, :2]).max() < 1e-4
    assert scale[2] == 1.0 and not codes[:, 2].any()  # a silent column stays silent


def test_acoular_hdf5_and_bursts_inside_one_long_file(tmp_path: Path) -> None:
    h5py = pytest.importorskip("h5py", reason="h5py is micam's optional HDF5 reader "
                               "(pip install 'micam[hdf5]')")
    toml = TOML.replace('bursts = ["p0s0.wav", "p0s1.wav"]',
                        'bursts = [{ file = "take.h5", start_sample = 100 }, '
                        '{ file = "take.h5", start_sample = 300 }]')
    spec = _folder(tmp_path, toml)
    data = np.random.default_rng(1).normal(0, 0.1, (500, 3)).astype(np.float32)
    with h5py.File(tmp_path / "take.h5", "w") as f:  # as Acoular's WriteH5 writes it
        f.create_dataset("time_data", data=data).attrs["sample_freq"] = float(FS)
    import_session(spec, tmp_path / "s")
    reader = SessionReader(tmp_path / "s")
    for k, start in ((0, 100), (1, 300)):
        codes, _ = reader.read_recording("pose/0000", f"speaker_{k}.wav")
        scale = np.array(reader.steps()["pose/0000"].files[f"speaker_{k}.wav"]
                         .meta["import_scale"])
        assert np.abs(codes / scale - data[start:start + N]).max() < 1e-4


REFUSALS = [
    # (TOML change, or a file to spoil, the words of the message)
    ('"p0s1.wav"', '"../p0s1.wav"', "recordings.poses[0].bursts[1]: '../p0s1.wav' must be a "
                                    "path inside"),
    ('"p0s1.wav"', '"/etc/passwd"', "recordings.poses[0].bursts[1]: '/etc/passwd' must be"),
    ('"ref1.wav"', '"nope.wav"', "recordings.references[1]: 'nope.wav' does not exist"),
    ('references = ["ref0.wav", "ref1.wav"]', 'references = ["ref0.wav"]',
     "recordings.references: 1 files for 2 speakers"),
    ('images = { cam0 = "p0.png" }', 'images = { cam1 = "p0.png" }',
     "recordings.poses[0].images: camera 'cam1' is not in cameras"),
    ("sample_rate_hz = 8000", "sample_rate_hz = 48000",
     "recordings.references[0]: 'ref0.wav' is sampled at 8000 Hz"),
    ("columns = [1, 2]", "columns = [1, 3]", "has 3 channels; the description reads column 3"),
    ("silence_after_samples = 5", "silence_after_samples = 2",
     "write extra_recorded_samples = 3 in [burst]"),
    ("width = 64", "width = 640", "is 64 x 48 pixels, camera cam0 is described as 640 x 48"),
    ("[recordings]", "[recordings]\nrefmic_images = { cam0 = \"p0.png\" }",
     "recordings.refmic_images: the reference microphone's image on its stand"),
    ("square_m = 0.03", "square_m = 30", "rig.square_m: Input should be less than or equal"),
]


@pytest.mark.parametrize(("old", "new", "words"), REFUSALS)
def test_a_wrong_import_names_its_field_and_writes_nothing(
        tmp_path: Path, old: str, new: str, words: str, capsys: pytest.CaptureFixture) -> None:
    assert old in TOML
    spec = _folder(tmp_path, TOML.replace(old, new))
    out = tmp_path / "session"
    assert main(["import", str(spec), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert words in err, err
    assert "write" in err or "should be" in err
    assert not out.exists()


def test_check_reads_every_file_and_writes_nothing(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture) -> None:
    spec = _folder(tmp_path)
    assert main(["import", str(spec), "--out", str(tmp_path / "s"), "--check"]) == 0
    assert "every file checked" in capsys.readouterr().out
    assert not (tmp_path / "s").exists()
    (tmp_path / "p0.png").write_bytes(b"not a png")
    with pytest.raises(ImportSpecError, match=r"recordings.poses\[0\].images.cam0: 'p0.png': "
                                              "not an image"):
        prepare(spec)


def test_an_existing_session_is_never_overwritten(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture) -> None:
    spec = _folder(tmp_path)
    assert main(["import", str(spec), "--out", str(tmp_path / "s")]) == 0
    journal = (tmp_path / "s" / "journal.jsonl").read_bytes()
    assert main(["import", str(spec), "--out", str(tmp_path / "s")]) == 2
    assert "never overwritten" in capsys.readouterr().err
    assert (tmp_path / "s" / "journal.jsonl").read_bytes() == journal


def _opencv_intrinsics(path: Path, dist: np.ndarray, width: int = W) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", width)
    fs.write("image_height", H)
    fs.write("camera_matrix", np.array([[80.0, 0, 32], [0, 80.0, 24], [0, 0, 1]]))
    fs.write("distortion_coefficients", dist.reshape(1, -1))
    fs.release()
    return path


def test_a_known_camera_calibration_is_read_into_the_session(tmp_path: Path) -> None:
    _opencv_intrinsics(tmp_path / "cam0.yaml", np.array([-0.1, 0.02, 0.0, 0.0]))
    toml = TOML.replace('height = 48', 'height = 48\nintrinsics_file = "cam0.yaml"\n'
                        'intrinsics_use = "fixed"')
    import_session(_folder(tmp_path, toml), tmp_path / "s")
    known = SessionReader(tmp_path / "s").capture["cameras"][0]["intrinsics"]
    assert known["use"] == "fixed" and known["camera_matrix"][0] == [80.0, 0.0, 32.0]
    assert known["distortion"] == [-0.1, 0.02, 0.0, 0.0, 0.0]  # 4 coefficients: k3 = 0


@pytest.mark.parametrize(("dist", "width", "words"), [
    (np.array([-0.1, 0.02, 0, 0, 0, 0.3, 0, 0]), W, "rational or thin-prism"),
    (np.zeros(5), 640, "calibrates images of 640 x 48 pixels"),
])
def test_an_intrinsics_file_of_another_model_or_size_is_refused(
        tmp_path: Path, dist: np.ndarray, width: int, words: str) -> None:
    path = _opencv_intrinsics(tmp_path / "c.json", dist, width)
    with pytest.raises(IntrinsicsFileError, match=words):
        read_intrinsics(path, "cam0", (W, H), "fixed")


def test_ros_and_micam_result_intrinsics(tmp_path: Path) -> None:
    ros = tmp_path / "ros.yaml"
    ros.write_text("image_width: 64\nimage_height: 48\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
                   "  data: [80, 0, 32, 0, 81, 24, 0, 0, 1]\ndistortion_coefficients:\n"
                   "  rows: 1\n  cols: 5\n  data: [0.1, 0, 0, 0, 0]\n")
    assert read_intrinsics(ros, "cam0", (W, H), "fixed").camera_matrix[1][1] == 81.0
    result = tmp_path / "result.json"
    result.write_text(json.dumps({"cameras": [{
        "name": "cam0", "width": W, "height": H, "K": [[80, 0, 32], [0, 80, 24], [0, 0, 1]],
        "dist": [0, 0, 0, 0, 0], "intrinsics_std": [0.1] * 9}]}))
    known = read_intrinsics(result, "cam0", (W, H))
    assert known.use == "prior" and known.std == (0.1,) * 9
    with pytest.raises(IntrinsicsFileError, match="without camera 'cam1'"):
        read_intrinsics(result, "cam1", (W, H))


DESIGN_XML = ('<?xml version="1.0" encoding="utf-8"?>\n<MicArray name="design">\n'
              '  <pos Name="Point 10" x="0.01" y="0.02" z="0.0"/>\n'
              '  <pos Name="Point 11" x="0.05" y="0.02" z="0.001"/>\n'
              '  <pos Name="Point 12" x="0.09" y="0.02" z="0.0"/>\n</MicArray>\n')


def test_the_maker_s_layout_file_is_read_into_the_session(tmp_path: Path) -> None:
    (tmp_path / "design").mkdir()
    (tmp_path / "design" / "array.xml").write_text(DESIGN_XML)
    toml = TOML.replace("[recordings]", '[layout]\nfile = "design/array.xml"\n'
                        "tolerance_m = 0.004\n[recordings]")
    import_session(_folder(tmp_path, toml), tmp_path / "s")
    layout = SessionReader(tmp_path / "s").capture["layout"]
    assert layout == {"mic_ids": [10, 11, 12],
                      "positions_m": [[0.01, 0.02, 0.0], [0.05, 0.02, 0.001],
                                      [0.09, 0.02, 0.0]],
                      "tolerance_m": 0.004, "source": "design/array.xml"}


@pytest.mark.parametrize(("layout", "words"), [
    ('file = "../array.xml"', "layout.file: '../array.xml' must be a path inside the TOML "
                              "file's folder"),
    ('file = "/etc/array.xml"', "layout.file: '/etc/array.xml' must be a path inside"),
    ('file = "absent.xml"', "layout.file: 'absent.xml' does not exist"),
    ('file = "bad.xml"', "layout.file: cannot read the layout"),
    ('file = "short.xml"', "layout.file: the layout"),
    ('file = "design.xml"\nmic_ids = [10, 11]', "layout: both file and mic_ids"),
    ("mic_ids = [10, 11]\npositions_m = [[0, 0, 0]]",
     "layout.positions_m: 1 positions for 2 microphone ids"),
    ("mic_ids = [10]\npositions_m = [[0, 0, 0]]", "layout.mic_ids: microphones [11] of the "
                                                   "channel map are not in the layout"),
    ("mic_ids = [10, 11]\npositions_m = [[0, 0, 0], [0, nan, 0]]",
     "layout.positions_m[1][1]: Input should be a finite number"),
])
def test_a_wrong_layout_is_refused_in_one_line_naming_its_field(
        tmp_path: Path, layout: str, words: str, capsys: pytest.CaptureFixture) -> None:
    """A path out of the folder, a missing file, a malformed XML, one that lacks microphones
    of the channel map, and wrong inline positions: each one line, the field and the fix."""
    (tmp_path / "bad.xml").write_text(DESIGN_XML[:-12])  # the closing tag cut off
    (tmp_path / "short.xml").write_text(DESIGN_XML.replace("Point 11", "Point 13"))
    (tmp_path / "design.xml").write_text(DESIGN_XML)
    spec = _folder(tmp_path, TOML.replace("[recordings]", f"[layout]\n{layout}\n[recordings]"))
    assert main(["import", str(spec), "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert words in err, err
    problems = [line for line in err.splitlines() if re.search(r"\blayout[.:\[]", line)]
    assert len(problems) == 1 and ("write" in problems[0] or "should be" in problems[0]), err
    assert not (tmp_path / "s").exists()


# ---------------------------------------------------------------------------------------------
# --check checks what the import would; a failed import leaves nothing behind


def _float_wav(path: Path, bad: float) -> None:
    x = np.zeros((N, 3))
    x[5, 1] = bad
    sf.write(path, x, FS, subtype="FLOAT")


def _truncated_png(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])  # the header is whole, the pixels are not


CONTENT_FAULTS = {
    # a fault only the file's content shows: (spoil the folder, the words of the message)
    "NaN sample": (lambda d: _float_wav(d / "p0s1.wav", np.nan),
                   "recordings.poses[0].bursts[1]: the recording holds NaN or infinite"),
    "infinite sample": (lambda d: _float_wav(d / "p0s0.wav", np.inf),
                        "recordings.poses[0].bursts[0]: the recording holds NaN or infinite"),
    "pixels cut off": (lambda d: _truncated_png(d / "p0.png"),
                       "recordings.poses[0].images.cam0: 'p0.png' is not an image OpenCV"),
}


@pytest.mark.parametrize("fault", sorted(CONTENT_FAULTS))
def test_check_checks_what_the_import_would_and_a_failed_import_can_be_retried(
        tmp_path: Path, fault: str, capsys: pytest.CaptureFixture) -> None:
    spec = _folder(tmp_path)
    spoil, words = CONTENT_FAULTS[fault]
    spoil(tmp_path)
    out = tmp_path / "session"
    before = sorted(tmp_path.iterdir())
    assert main(["import", str(spec), "--out", str(out), "--check"]) == 2
    assert words in capsys.readouterr().err
    assert main(["import", str(spec), "--out", str(out)]) == 2
    assert words in capsys.readouterr().err
    assert sorted(tmp_path.iterdir()) == before  # no session, no staging directory left
    _folder(tmp_path)  # the files mended: the same command now succeeds
    assert main(["import", str(spec), "--out", str(out)]) == 0
    assert SessionReader(out).status == "complete"


def test_a_failed_import_into_an_empty_directory_leaves_it_empty(tmp_path: Path) -> None:
    spec = _folder(tmp_path)
    CONTENT_FAULTS["NaN sample"][0](tmp_path)
    out = tmp_path / "empty"
    out.mkdir()
    with pytest.raises(ImportSpecError):
        import_session(spec, out)
    assert out.is_dir() and not any(out.iterdir())


@pytest.mark.parametrize(("make", "words"), [
    (lambda out: out.symlink_to(out.parent / "nowhere"), "is a symbolic link to"),
    (lambda out: out.write_text("x"), "is a file, not a directory"),
    (lambda out: (out.mkdir(), (out / "notes.txt").write_text("x")), "is not empty"),
    (lambda out: out.parent.joinpath("f").write_text("x"), "which is not a directory"),
])
def test_an_output_that_cannot_be_a_new_session_is_refused_first(
        tmp_path: Path, make, words: str, capsys: pytest.CaptureFixture) -> None:
    spec = _folder(tmp_path)
    out = tmp_path / "out"
    make(out)
    target = tmp_path / "f" / "s" if (tmp_path / "f").exists() else out
    before = {p: p.lstat().st_mtime_ns for p in tmp_path.rglob("*")}
    for check in ([], ["--check"]):
        assert main(["import", str(spec), "--out", str(target), *check]) == 2
        err = capsys.readouterr().err
        assert err.startswith("micam: error: --out ") and words in err, err
    assert {p: p.lstat().st_mtime_ns for p in tmp_path.rglob("*")} == before


def test_a_description_of_too_many_poses_is_refused(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture) -> None:
    from acquisition.importer import MAX_POSES

    pose = '[[recordings.poses]]\nbursts = ["p0s0.wav", "p0s1.wav"]\n'
    spec = _folder(tmp_path, TOML + pose * MAX_POSES)
    assert main(["import", str(spec), "--out", str(tmp_path / "s"), "--check"]) == 2
    assert f"recordings.poses: Tuple should have at most {MAX_POSES} items" in \
        capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# Sizes come from headers, and --check holds one step's files at a time


_IMPORTED = """
from micam.cli import main
import acquisition.importer, micam.commands.import_session  # their imports are not measured
"""


@pytest.mark.slow
def test_a_huge_image_is_refused_from_its_header(tmp_path: Path) -> None:
    """A 16000 x 16000 PNG of one colour (250 kB, 256 MB decoded) where the camera is
    described at that size: refused before it is decoded."""
    toml = TOML.replace("width = 64\nheight = 48", "width = 16000\nheight = 16000")
    spec = _folder(tmp_path, toml)
    (tmp_path / "p0.png").write_bytes(blank_png(16000, 16000))
    grown, done = peak_growth(_IMPORTED, f"""
        print("status", main(["import", {str(spec)!r}, "--out", {str(tmp_path / "s")!r},
                              "--check"]))
        """)
    assert "status 2" in done.stdout and "more than the 100000000 pixels" in done.stderr, done
    assert grown < 64 * 2**20, f"--check grew the peak memory by {grown / 2**20:.0f} MiB"


@pytest.mark.slow
def test_the_memory_of_check_does_not_grow_with_the_poses(tmp_path: Path) -> None:
    """100 poses naming one 2000 x 1000 image (2 MB decoded; 200 MB if all were held):
    --check holds one step's files at a time."""
    toml = TOML.replace("width = 64\nheight = 48", "width = 2000\nheight = 1000")
    pose = '[[recordings.poses]]\nbursts = ["p0s0.wav", "p0s1.wav"]\nimages = { cam0 = "p0.png" }\n'
    spec = _folder(tmp_path, toml + pose * 99)
    cv2.imwrite(str(tmp_path / "p0.png"), np.zeros((1000, 2000), np.uint8))
    grown, done = peak_growth(_IMPORTED, f"""
        print("status", main(["import", {str(spec)!r}, "--out", {str(tmp_path / "s")!r},
                              "--check"]))
        """)
    assert "status 0" in done.stdout and "100 poses" in done.stdout, done
    assert grown < 48 * 2**20, f"--check grew the peak memory by {grown / 2**20:.0f} MiB"
