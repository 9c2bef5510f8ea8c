"""`micam import`: a micam session from what any recorder produces.

Input: one TOML file (the rig and array description of acquisition/contracts/rig_description.py plus a
`[recordings]` table naming the files), beside it a folder of recordings (WAV, FLAC, RF64 or
anything else libsndfile reads; HDF5 time data as Acoular writes it: a dataset `time_data` of
shape (samples, channels) with the attribute `sample_freq`, read with h5py, an optional
dependency) and images (PNG, JPEG, ... as OpenCV reads them). Output: a session written
through the session store (journal, checksums, atomic files), whose capture is the
description itself, so that `micam calibrate` reads it like any other.

Everything is checked before the session is created (every field, every file's existence,
format, sample rate, length, channel count and image size), so that a mistake costs nothing
but the message, which names the TOML field, what is wrong and what to write instead.

Recordings are stored as 16-bit codes, as the session format asks: 16-bit integer sources bit
for bit; any other sample format (24/32-bit integers, floats) is scaled per column so that its
largest magnitude is full scale and rounded (quantization noise 98 dB below that peak, far
below any microphone's own); the factor (codes per source unit) is kept per column in the
recording's meta, `import_scale`.
"""

from __future__ import annotations

import contextlib
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any, Literal

import cv2
import numpy as np
import soundfile as sf
from pydantic import Field, ValidationError, model_validator

from acquisition.contracts.config_model import ConfigModel
from acquisition.contracts.errors import UserError
from .intrinsics_file import IntrinsicsFileError, read_intrinsics
from acquisition.contracts.rig_description import (
    CameraDescription,
    RigArrayDescription,
    problem_text,
)
from acquisition.contracts.session import SessionError, SessionWriter, sha256_file
from acquisition.contracts.session._writer import MAX_CHANNELS
from acquisition.contracts.step_ids import REFMIC_STEP, pose_step, reference_step

MAX_SPEC_BYTES = 4_000_000
"""The import TOML: a description and a list of files, far below this."""
MAX_IMAGE_BYTES = 256 * 2**20
"""Largest image file read (a 100-megapixel RGB PNG is about this size)."""
HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf")
CODE_FULL_SCALE = 32767


class ImportSpecError(UserError):
    """The import TOML or its files cannot make a session; the message says what to change."""


class BurstFile(ConfigModel):
    """A recording of one burst: a file, where in it the burst's recording starts and, for
    HDF5, which dataset holds it."""

    file: str = Field(examples=["pose00/speaker0.wav"],
                      description="path relative to the TOML file")
    start_sample: int = Field(default=0, ge=0, examples=[0],
                              description="first sample of this burst's recording in the file")
    dataset: str = Field(default="time_data", examples=["time_data"],
                         description="HDF5 only: the dataset of shape (samples, channels)")


FileRef = str | BurstFile
"""A burst recording: a file that holds exactly one recording, or a `BurstFile` table."""


class PoseFiles(ConfigModel):
    """One rig pose: every speaker's burst recording, in speaker order, and the cameras'
    images of the board."""

    bursts: tuple[FileRef, ...] = Field(
        min_length=1, examples=[["pose00/speaker0.wav", "pose00/speaker1.wav"]],
        description="one recording per speaker, in speaker order")
    images: dict[str, str] = Field(
        default_factory=dict, examples=[{"cam0": "pose00/cam0.png"}],
        description="camera name -> image file (a camera that missed the pose is left out)")


class RecordingFiles(ConfigModel):
    """The files of the session, paths relative to the TOML file."""

    references: tuple[FileRef, ...] = Field(
        min_length=1, examples=[["reference/speaker0.wav", "reference/speaker1.wav"]],
        description="the reference recording of each speaker (the reference microphone close "
                    "to it), in speaker order")
    refmic_images: dict[str, str] | None = Field(
        default=None, examples=[{"cam0": "refmic/cam0.png"}],
        description="images of the reference microphone on its stand touched by the rig's "
                    "reference mark (only with the reference microphone in the pose "
                    "recordings)")
    poses: tuple[PoseFiles, ...] = Field(min_length=1)


class ImportCamera(CameraDescription):
    """A camera of the import: as in the description, or with its known calibration given as
    a file (OpenCV YAML/JSON/XML, ROS camera_info or a micam result.json)."""

    intrinsics_file: str | None = Field(
        default=None, examples=["cam0_intrinsics.yaml"],
        description="a known calibration of this camera, relative to the TOML file")
    intrinsics_use: Literal["prior", "fixed"] = Field(
        default="prior", examples=["fixed"],
        description="how to use the file: 'fixed' as given, 'prior' weighted by intrinsics_std")
    intrinsics_std: tuple[float, float, float, float, float, float, float, float,
                          float] | None = Field(
        default=None, examples=[[0.5, 0.5, 0.5, 0.5, 0.002, 0.01, 1e-4, 1e-4, 0.02]],
        description="standard deviations of fx, fy, cx, cy (px), k1, k2, p1, p2, k3 for a "
                    "prior (default: the file's, if it is a micam result)")


class ImportSpec(RigArrayDescription):
    """The import TOML: the rig and array description, the cameras (optionally with a known
    calibration file) and the recordings."""

    cameras: tuple[ImportCamera, ...] = Field(min_length=1,  # type: ignore[assignment]
                                              description="camera 0 (the frame) first")
    recordings: RecordingFiles
    session_id: str | None = Field(default=None, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$",
                                   examples=["lab-2026-03-02"])

    @model_validator(mode="after")
    def _files_fit_the_description(self) -> ImportSpec:
        problems = self._recording_problems()
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def _recording_problems(self) -> list[str]:
        problems = []
        n = self.n_speakers
        rec = self.recordings
        if len(rec.references) != n:
            problems.append(f"recordings.references: {len(rec.references)} files for {n} "
                            "speakers; write one reference recording per speaker, in order")
        cameras = [c.name for c in self.cameras]
        for i, pose in enumerate(rec.poses):
            if len(pose.bursts) != n:
                problems.append(f"recordings.poses[{i}].bursts: {len(pose.bursts)} files for "
                                f"{n} speakers; write one recording per speaker, in order")
            unknown = sorted(set(pose.images) - set(cameras))
            if unknown:
                problems.append(f"recordings.poses[{i}].images: camera {unknown[0]!r} is not "
                                f"in cameras ({', '.join(cameras)}); write one of those names")
        if rec.refmic_images is not None:
            if self.reference.pose_recordings_column is None:
                problems.append(
                    "recordings.refmic_images: the reference microphone's image on its stand "
                    "is only of use when the pose recordings hold it; write "
                    "reference.pose_recordings_column = ..., or leave refmic_images out")
            if self.rig.reference_mark_m is None:
                problems.append("recordings.refmic_images: needs rig.reference_mark_m, the rig "
                                "point touched to the reference microphone; write it, e.g. "
                                "reference_mark_m = [-0.09, -0.06, 0.0]")
            unknown = sorted(set(rec.refmic_images) - set(cameras))
            if unknown:
                problems.append(f"recordings.refmic_images: camera {unknown[0]!r} is not in "
                                "cameras; write one of their names")
        for i, c in enumerate(self.cameras):
            if c.intrinsics_file is not None and c.intrinsics is not None:
                problems.append(f"cameras[{i}]: both intrinsics and intrinsics_file are given; "
                                "write only one of them")
            if (c.intrinsics_file is not None and c.intrinsics_use == "prior"
                    and c.intrinsics_std is None and not c.intrinsics_file.endswith(".json")):
                problems.append(f"cameras[{i}].intrinsics_std: a prior needs its standard "
                                "deviations; write intrinsics_std = [fx, fy, cx, cy, k1, k2, "
                                "p1, p2, k3], or intrinsics_use = 'fixed'")
        return problems


def load_spec(path: Path) -> ImportSpec:
    """Read and validate an import TOML.

    Raises:
        ImportSpecError: unreadable, not TOML, or invalid (one line per problem).
    """
    path = Path(path)
    try:
        if path.stat().st_size > MAX_SPEC_BYTES:
            raise ImportSpecError(f"{path} is larger than {MAX_SPEC_BYTES} bytes; an import "
                                  "description is a few kilobytes")
        document = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ImportSpecError(f"import description {path} does not exist") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ImportSpecError(f"{path} is not a readable TOML file: {exc}") from None
    try:
        return ImportSpec.model_validate(document)
    except ValidationError as exc:
        raise ImportSpecError(problem_text(f"import description {path}", exc, ImportSpec)
                              .rstrip("\n")) from None


# ---------------------------------------------------------------------------------------------
# Files


def inside(base: Path, relative: str, where: str) -> Path:
    """`relative` as a path inside `base`, refusing anything that leaves it.

    Raises:
        ImportSpecError: an absolute path, a `..`, or a link out of `base`.
    """
    pure = PurePosixPath(relative)
    if pure.is_absolute() or ".." in pure.parts or not relative.strip():
        raise ImportSpecError(f"{where}: {relative!r} must be a path inside the TOML file's "
                              "folder; write it relative to that folder (no leading '/', no "
                              "'..')")
    path = base / pure
    if not path.resolve().is_relative_to(base.resolve()):
        raise ImportSpecError(f"{where}: {relative!r} leads out of the TOML file's folder "
                              "(through a link); copy the file into that folder and write its path")
    if not path.is_file():
        raise ImportSpecError(f"{where}: {relative!r} does not exist (looked for {path}); "
                              "write the path relative to the TOML file")
    return path


@dataclass(frozen=True)
class _Recording:
    """A checked burst recording, read on demand."""

    where: str
    path: Path
    start: int
    frames: int
    dataset: str
    source_format: str

    def codes(self) -> tuple[np.ndarray, list[float] | None]:
        """(frames, channels) int16 codes and the per-column scale (None: bit for bit)."""
        if self.path.suffix.lower() in HDF5_SUFFIXES:
            with _hdf5(self.path, self.where) as f:
                data = np.asarray(f[self.dataset][self.start:self.start + self.frames])
        elif self.source_format.endswith("PCM_16"):
            data, _ = sf.read(self.path, start=self.start, frames=self.frames, dtype="int16",
                              always_2d=True)
            return np.ascontiguousarray(data), None
        else:
            data, _ = sf.read(self.path, start=self.start, frames=self.frames,
                              dtype="float64", always_2d=True)
        return _requantize(np.asarray(data, dtype=np.float64), self.where)


def _requantize(data: np.ndarray, where: str) -> tuple[np.ndarray, list[float]]:
    """16-bit codes of a recording in another format, scaled per column to its peak."""
    if not np.all(np.isfinite(data)):
        raise ImportSpecError(f"{where}: the recording holds NaN or infinite samples; write "
                              "the path of a recording without them")
    peak = np.max(np.abs(data), axis=0)
    scale = np.where(peak > 0, CODE_FULL_SCALE / np.where(peak > 0, peak, 1.0), 1.0)
    codes = np.rint(data * scale).astype(np.int16)
    return codes, [float(s) for s in scale]


def _hdf5(path: Path, where: str) -> Any:
    try:
        import h5py
    except ImportError:
        raise ImportSpecError(
            f"{where}: {path.name} is HDF5, which needs h5py: pip install 'micam[hdf5]' (or "
            "write the path of a WAV or FLAC file instead)") from None
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise ImportSpecError(f"{where}: {path.name} is not a readable HDF5 file ({exc}); "
                              "write the path of one") from None


def check_recording(base: Path, ref: FileRef, where: str, description: RigArrayDescription,
                    last_column: int) -> _Recording:
    """A burst recording checked against the description: it exists, is audio at the
    sample rate, holds the columns read and one burst's samples from its start.

    Raises:
        ImportSpecError: naming `where` (the TOML field), the problem and the fix.
    """
    entry = BurstFile(file=ref) if isinstance(ref, str) else ref
    path = inside(base, entry.file, where)
    if path.suffix.lower() in HDF5_SUFFIXES:
        rate, frames, channels, fmt = _hdf5_info(path, entry.dataset, where)
    else:
        try:
            info = sf.info(str(path))
        except (sf.LibsndfileError, RuntimeError) as exc:
            raise ImportSpecError(f"{where}: {entry.file!r} is not a sound file libsndfile "
                                  f"reads ({exc}); convert it to WAV or FLAC and write that "
                                  "file's path") from None
        rate, frames, channels = float(info.samplerate), info.frames, info.channels
        fmt = f"{info.format} {info.subtype}"
    n = description.burst.n_samples
    if round(rate) != round(description.sample_rate_hz):
        raise ImportSpecError(f"{where}: {entry.file!r} is sampled at {rate:g} Hz, the "
                              f"description says sample_rate_hz = "
                              f"{description.sample_rate_hz:g}; write the recorder's rate")
    if not last_column < channels <= MAX_CHANNELS:
        raise ImportSpecError(
            f"{where}: {entry.file!r} has {channels} channels; the description reads column "
            f"{last_column}: write the columns this file has (they count from 0)"
            if channels <= MAX_CHANNELS else
            f"{where}: {entry.file!r} has {channels} channels, more than {MAX_CHANNELS}; split "
            "it into files of fewer channels and write those")
    if frames < entry.start_sample + n:
        raise ImportSpecError(
            f"{where}: {entry.file!r} has {frames} samples, fewer than start_sample "
            f"{entry.start_sample} + the burst layout's {n}; write the layout the recorder "
            "used in [burst] (silence_before_samples, mls_order, periods, silence_after_samples, "
            "extra_recorded_samples)")
    if isinstance(ref, str) and frames != n:
        raise ImportSpecError(
            f"{where}: {entry.file!r} has {frames} samples, the burst layout {n}; if the "
            f"recorder kept more, write extra_recorded_samples = "
            f"{frames - n + description.burst.extra_recorded_samples} in [burst], or give "
            "the burst's place as {{ file = ..., start_sample = ... }}")
    return _Recording(where, path, entry.start_sample, n, entry.dataset, fmt)


def _hdf5_info(path: Path, dataset: str, where: str) -> tuple[float, int, int, str]:
    """Sample rate, frames, channels and format of Acoular-style HDF5 time data."""
    with _hdf5(path, where) as f:
        if dataset not in f or not hasattr(f[dataset], "shape"):
            raise ImportSpecError(f"{where}: {path.name} has no dataset {dataset!r}; Acoular "
                                  "writes its time data as 'time_data'; write the dataset's "
                                  "name as dataset = '...'")
        ds = f[dataset]
        if ds.ndim != 2:
            raise ImportSpecError(f"{where}: {path.name}:{dataset} has shape {ds.shape}; "
                                  "write the name of a dataset of shape (samples, channels)")
        rate = ds.attrs.get("sample_freq", f.attrs.get("sample_freq"))
        if rate is None:
            raise ImportSpecError(f"{where}: {path.name}:{dataset} has no 'sample_freq' "
                                  "attribute (Acoular's sample rate); write the rate in Hz "
                                  "into that attribute")
        return float(np.asarray(rate).ravel()[0]), int(ds.shape[0]), int(ds.shape[1]), \
            f"HDF5 {ds.dtype}"


def read_image(base: Path, relative: str, where: str, camera: CameraDescription) -> np.ndarray:
    """An image as the session stores it (uint8 grey or BGR), checked against the camera's
    size."""
    path = inside(base, relative, where)
    if path.stat().st_size > MAX_IMAGE_BYTES:
        raise ImportSpecError(f"{where}: {relative!r} is larger than {MAX_IMAGE_BYTES} bytes; "
                              "write the path of the camera's own image")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImportSpecError(f"{where}: {relative!r} is not an image OpenCV reads; convert "
                              "it to PNG and write that file's path")
    if image.dtype == np.uint16:
        image = np.rint(image / 257.0).astype(np.uint8)
    if image.dtype != np.uint8:
        raise ImportSpecError(f"{where}: {relative!r} has {image.dtype} pixels; write the "
                              "path of an 8- or 16-bit image")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if (image.shape[1], image.shape[0]) != (camera.width, camera.height):
        raise ImportSpecError(
            f"{where}: {relative!r} is {image.shape[1]} x {image.shape[0]} pixels, camera "
            f"{camera.name} is described as {camera.width} x {camera.height}; write its real "
            "size in [[cameras]]")
    return np.ascontiguousarray(image)


# ---------------------------------------------------------------------------------------------
# The plan and the session


@dataclass(frozen=True)
class _Step:
    """A session step to write: its recordings (file name -> recording, speaker) and images
    (camera -> (relative path, TOML field))."""

    id: str
    recordings: tuple[tuple[str, _Recording, int], ...]
    images: tuple[tuple[str, str, str], ...]


def description_of(spec: ImportSpec, base: Path) -> RigArrayDescription:
    """The description the session stores: the spec's, with the cameras' intrinsics files
    read into values."""
    cameras = []
    for i, c in enumerate(spec.cameras):
        known = c.intrinsics
        if c.intrinsics_file is not None:
            where = f"cameras[{i}].intrinsics_file"
            try:
                known = read_intrinsics(inside(base, c.intrinsics_file, where), c.name,
                                        (c.width, c.height), c.intrinsics_use, c.intrinsics_std)
            except IntrinsicsFileError as exc:
                raise ImportSpecError(f"{where}: {exc} (write the path of another calibration, "
                                      "or leave intrinsics_file out to calibrate the camera "
                                      "from its images)") from None
        cameras.append(CameraDescription(name=c.name, width=c.width, height=c.height,
                                         intrinsics=known))
    fields = spec.model_dump(exclude={"cameras", "recordings", "session_id"})
    try:
        return RigArrayDescription.model_validate({**fields, "cameras": cameras})
    except ValidationError as exc:
        raise ImportSpecError(problem_text("the imported description", exc,
                                           RigArrayDescription)) from None


def plan(spec: ImportSpec, base: Path) -> list[_Step]:
    """Every step of the session, each file checked (see `check_recording`)."""
    rec = spec.recordings
    mic_columns = [c for _, c, _ in spec.microphones()]
    pose_last = max([*mic_columns, spec.reference.pose_recordings_column or 0])
    steps = [
        _Step(reference_step(k), ((f"speaker_{k}.wav", check_recording(
            base, ref, f"recordings.references[{k}]", spec,
            spec.reference.reference_recordings_column), k),), ())
        for k, ref in enumerate(rec.references)
    ]
    if rec.refmic_images:
        steps.append(_Step(REFMIC_STEP, (), tuple(
            (camera, path, f"recordings.refmic_images.{camera}")
            for camera, path in rec.refmic_images.items())))
    for i, pose in enumerate(rec.poses):
        where = f"recordings.poses[{i}]"
        recordings = tuple(
            (f"speaker_{k}.wav", check_recording(base, ref, f"{where}.bursts[{k}]", spec,
                                                 pose_last), k)
            for k, ref in enumerate(pose.bursts))
        images = tuple((camera, path, f"{where}.images.{camera}")
                       for camera, path in pose.images.items())
        for _, path, field in images:
            inside(base, path, field)
        steps.append(_Step(pose_step(i), recordings, images))
    return steps


@dataclass(frozen=True)
class Prepared:
    """An import checked in full and ready to write: the description the session stores,
    its steps, and the images already decoded."""

    spec: ImportSpec
    base: Path
    description: RigArrayDescription
    steps: list[_Step]
    images: dict[tuple[str, str], np.ndarray]


def prepare(spec_path: Path) -> Prepared:
    """Read the import TOML and check every field and file (images decoded, recordings'
    headers read).

    Raises:
        ImportSpecError: the TOML or a file is wrong.
    """
    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    base = spec_path.parent
    description = description_of(spec, base)
    steps = plan(spec, base)
    cameras = {c.name: c for c in description.cameras}
    images = {(s.id, camera): read_image(base, path, field, cameras[camera])
              for s in steps for camera, path, field in s.images}
    return Prepared(spec, base, description, steps, images)


def import_session(spec_path: Path, out: Path,
                   on_step: Callable[[str], None] | None = None) -> Path:
    """Build a session in `out` from the import TOML at `spec_path` and its files.

    Every field and file is checked before `out` is created (`prepare`); a failure while
    writing (a full disk, a file that changed) stops the session as failed, with the reason,
    and raises.

    Raises:
        ImportSpecError: the TOML or a file is wrong (nothing written).
        SessionError: `out` is not new or empty, or the store refused a write.
    """
    p = prepare(spec_path)
    writer = SessionWriter.create(out, capture=p.description.model_dump(mode="json"),
                                  session_id=p.spec.session_id)
    sources: dict[str, str] = {}
    try:
        for step in p.steps:
            writer.begin_step(step.id)
            for camera, path, _ in step.images:
                writer.write_image(step.id, f"{camera}.png", p.images[(step.id, camera)],
                                   meta={"source": path})
                sources[path] = sha256_file(p.base / path).sha256
            for name, recording, speaker in step.recordings:
                codes, scale = recording.codes()
                source = recording.path.relative_to(p.base).as_posix()
                writer.write_recording(
                    step.id, name, codes, round(p.description.sample_rate_hz),
                    meta={"speaker": speaker, "source": source, "start_sample": recording.start,
                          "source_format": recording.source_format, "import_scale": scale})
                sources[source] = sha256_file(recording.path).sha256
            writer.end_step(step.id)
            if on_step is not None:
                on_step(step.id)
        writer.begin_step("import")
        writer.write_json("import", "import.json", {
            "description_toml": Path(spec_path).read_text(encoding="utf-8"),
            "sources_sha256": sources,
        })
        writer.end_step("import")
        writer.stop("success")
    except BaseException as exc:
        with contextlib.suppress(SessionError, OSError):  # the first error is the one to tell
            writer.stop("failed", f"import stopped: {type(exc).__name__}: {exc}")
        raise
    return Path(out)


__all__ = ["ImportSpec", "ImportSpecError", "Prepared", "import_session", "load_spec", "prepare"]
