"""Property-based fuzzing of `micam import`: random import descriptions through `--check` and
the import itself, in this process through `micam.cli.main`.

Each example starts from a valid description of a small folder and changes a few of its
fields at random: wrong types, huge and non-finite numbers, paths with `..`, absolute paths,
links out of the folder and within it, missing files, directories and FIFOs, files of random
or mangled content (WAV, FLAC, PNG, HDF5). Whatever it holds:

- the outcome is exit 0 or 2, never 70 ("a bug") and never a traceback;
- nothing outside --out is written or changed;
- a failed import leaves --out as it was (absent), so the same command can be run again;
- --check and the import agree: --check passes exactly when the import succeeds.

The default run is bounded (MICAM_FUZZ_EXAMPLES, default 40, a few seconds); the long run is
`MICAM_LONG_TESTS=1` (3000 examples, a few minutes), see docs/security.md.
"""

from __future__ import annotations

import copy
import functools
import io
import json
import math
import os
import shutil
import tempfile
import tomllib
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import soundfile as sf
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acquisition.contracts.session import SessionReader
from micam.cli import main
from tests.acquisition.test_import import FS, TOML, N, _folder

LONG = os.environ.get("MICAM_LONG_TESTS") == "1"
EXAMPLES = int(os.environ.get("MICAM_FUZZ_EXAMPLES", "3000" if LONG else "40"))
pytestmark = pytest.mark.timeout(4 * 3600 if LONG else 300)

BASE: dict[str, Any] = tomllib.loads(TOML)
BASE["recordings"]["poses"].append({  # a second pose: an HDF5 take and a FLAC
    "bursts": [{"file": "take.h5", "start_sample": 10}, "p1s1.flac"],
    "images": {"cam0": "p1.png"}})

PATHS = ["ref0.wav", "p0.png", "take.h5", "p1s1.flac", "nan.wav", "nan.wav", "huge.png",
         "../outside/secret.wav", "/etc/passwd", "link_out.wav", "link_in.wav", "missing.wav",
         "dir", "fifo", "random.wav", "random.png", "random.flac", "random.h5", "mangled.wav",
         "mangled.png", "mangled.flac", "", ".", "a/../../x", "x" * 300, "dir/../ref0.wav",
         "ref0.wav\u0000"]


def _toml(value: Any) -> str:
    """`value` as TOML (inline tables and arrays; every key quoted)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") \
            if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k, ensure_ascii=False)} = {_toml(v)}"
                           for k, v in value.items()) + "}"


def _document(doc: dict[str, Any]) -> str:
    return "".join(f"{json.dumps(k, ensure_ascii=False)} = {_toml(v)}\n" for k, v in doc.items())


def _places(value: Any, at: tuple = ()) -> list[tuple]:
    """Every key path into `value` (tables and arrays), the top level included."""
    places = [at]
    items = value.items() if isinstance(value, dict) else \
        enumerate(value) if isinstance(value, list) else ()
    for key, inner in items:
        places.extend(_places(inner, (*at, key)))
    return places


text = st.text(st.characters(exclude_categories=["Cs"]), max_size=8)
numbers = st.one_of(st.integers(-3, 70), st.sampled_from([0, -1, 2**31, 2**63, 10**30, -10**30]),
                    st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([1e308, -0.0, 8000.0, 1e-300]))
paths = st.sampled_from(PATHS)
leaves = st.one_of(paths, numbers, text, st.booleans())
values = st.one_of(
    leaves, paths, paths,
    st.builds(lambda f, s, d: {"file": f, "start_sample": s, "dataset": d}, paths, numbers,
              st.sampled_from(["time_data", "missing", "group", "ext", "strings", "nan_data",
                               ""])),
    st.lists(leaves, max_size=4), st.dictionaries(st.sampled_from(["cam0", "cam1", "x"]), paths,
                                                  max_size=2),
    st.lists(st.lists(numbers, max_size=3), max_size=3))


def _mangle(data: bytes, draw) -> bytes:
    """`data` cut short and with some bytes changed, as `draw` decides."""
    cut = draw(st.integers(0, len(data)))
    spoilt = bytearray(data[:cut] if draw(st.booleans()) else data)
    for at, byte in draw(st.lists(st.tuples(st.integers(0, max(len(spoilt) - 1, 0)),
                                            st.integers(0, 255)), max_size=6)):
        if spoilt:
            spoilt[at] = byte
    return bytes(spoilt)


def _valid_files(root: Path) -> None:
    """The valid files of the folder `root / "lab"`, a file outside it and the links and
    entries that are not files."""
    import h5py

    folder = root / "lab"
    folder.mkdir()
    _folder(folder)
    rng = np.random.default_rng(1)
    sf.write(folder / "p1s1.flac", rng.normal(0, 0.1, (N, 3)), FS, subtype="PCM_24")
    cv2.imwrite(str(folder / "p1.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    with h5py.File(folder / "take.h5", "w") as f:
        f.create_dataset("time_data", data=rng.normal(0, 0.1, (200, 3))).attrs["sample_freq"] = \
            float(FS)
        f.create_dataset("strings", data=np.array([b"a", b"b"]))
        f.create_dataset("nan_data", data=np.full((200, 3), np.nan)).attrs["sample_freq"] = FS
        f.create_group("group")
        f["ext"] = h5py.ExternalLink(str(root / "outside" / "secret.h5"), "time_data")
    (root / "outside").mkdir()
    sf.write(root / "outside" / "secret.wav", np.zeros((N, 3), np.int16), FS, subtype="PCM_16")
    (folder / "link_out.wav").symlink_to(root / "outside" / "secret.wav")
    (folder / "link_in.wav").symlink_to("ref0.wav")
    nan = np.zeros((N, 3))
    nan[N // 2, 1] = np.nan
    sf.write(folder / "nan.wav", nan, FS, subtype="FLOAT")  # a header like any other
    (folder / "dir").mkdir()
    (folder / "huge.png").write_bytes(_header_only_png(16000, 16000))


_SCRATCH = "/dev/shm" if os.access("/dev/shm", os.W_OK) else None
"""Memory-backed scratch space where there is one: the session store's fsyncs cost nothing."""


@functools.cache
def _template() -> tempfile.TemporaryDirectory:
    """The valid files, made once per run."""
    template = tempfile.TemporaryDirectory(prefix="micam-import-fuzz-", dir=_SCRATCH)
    _valid_files(Path(template.name))
    return template


def _lay_out(root: Path, draw) -> Path:
    """The folder of the description (a copy of the valid files, links kept as links) with
    a FIFO and files of random and of mangled content; returns the TOML file's path."""
    shutil.copytree(_template().name, root, symlinks=True, dirs_exist_ok=True)
    folder = root / "lab"
    (folder / "link_out.wav").unlink()  # the copy's own outside file
    (folder / "link_out.wav").symlink_to(root / "outside" / "secret.wav")
    os.mkfifo(folder / "fifo")
    for suffix in ("wav", "png", "flac", "h5"):
        (folder / f"random.{suffix}").write_bytes(draw(st.binary(max_size=300)))
    for name, source in (("mangled.wav", "ref0.wav"), ("mangled.png", "p1.png"),
                         ("mangled.flac", "p1s1.flac")):
        (folder / name).write_bytes(_mangle((folder / source).read_bytes(), draw))
    return folder / "import.toml"


def _changed(doc: dict[str, Any], draw) -> dict[str, Any]:
    """`doc` with 0 to 4 changes: mostly a file path replaced (by another path, or a burst
    table), else any field replaced by a value of any type or deleted."""
    doc["cameras"][0]["intrinsics_file"] = draw(st.none() | paths, label="intrinsics_file")
    if doc["cameras"][0]["intrinsics_file"] is None:
        del doc["cameras"][0]["intrinsics_file"]
    else:
        doc["cameras"][0]["intrinsics_use"] = "fixed"
    for _ in range(draw(st.integers(0, 4), label="changes")):
        places = _places(doc)[1:]
        files = [at for at in places if at[0] == "recordings" and isinstance(_at(doc, at), str)]
        if files and draw(st.integers(0, 9), label="a path?") < 7:
            place = draw(st.sampled_from(files), label="file")
            value = draw(st.one_of(paths, values), label="path")
        else:
            place = draw(st.sampled_from(places), label="place")
            value = None if draw(st.integers(0, 5), label="delete?") == 0 else \
                draw(values, label="value")
        *parent_at, key = place
        parent = _at(doc, tuple(parent_at))
        if value is None:
            del parent[key]
        else:
            parent[key] = value
    return doc


def _at(doc: Any, place: tuple) -> Any:
    for step in place:
        doc = doc[step]
    return doc


def _header_only_png(width: int, height: int) -> bytes:
    """A PNG whose header states `width` x `height` (its pixels are cut off)."""
    ok, png = cv2.imencode(".png", np.zeros((1, 1), np.uint8))
    assert ok
    data = bytearray(png.tobytes())
    data[16:24] = width.to_bytes(4, "big") + height.to_bytes(4, "big")  # IHDR (CRC left wrong)
    return bytes(data)


def _tree(root: Path, out: Path) -> dict[str, tuple[int, int]]:
    """Every entry under `root` but `out`, with its size and modification time."""
    entries = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = [d for d in dirnames if here / d != out]
        for name in (*dirnames, *filenames):
            path = here / name
            if path == out:
                continue
            info = path.lstat()
            entries[str(path.relative_to(root))] = (info.st_size, info.st_mtime_ns)
    return entries


def _run(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with redirect_stdout(io.StringIO()), redirect_stderr(err):
        status = main(argv)
    return status, err.getvalue()


@settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=not LONG,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=st.data())
@pytest.mark.slow
def test_any_import_description_ends_in_a_session_or_one_clear_line(data: st.DataObject
                                                                      ) -> None:
    with tempfile.TemporaryDirectory(dir=_SCRATCH) as directory:
        root = Path(directory)
        spec = _lay_out(root, data.draw)
        doc = _changed(copy.deepcopy(BASE), data.draw)
        spec.write_text(_document(doc), encoding="utf-8")
        out = root / "session"
        before = _tree(root, out)

        checked, check_err = _run(["import", str(spec), "--out", str(out), "--check"])
        imported, import_err = _run(["import", str(spec), "--out", str(out)])

        for status, err in ((checked, check_err), (imported, import_err)):
            assert status in (0, 2), err
            assert "Traceback" not in err and "bug in micam" not in err, err
            assert status == 0 or (err.startswith("micam: error: ") and err.endswith("\n")), err
        assert _tree(root, out) == before, "a file outside --out was written or changed"
        assert (checked == 0) == (imported == 0), (check_err, import_err)
        if imported == 0:
            assert SessionReader(out).status == "complete"
        else:
            assert not out.exists() and not out.is_symlink(), "a failed import left --out"
