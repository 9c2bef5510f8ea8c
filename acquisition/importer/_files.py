"""The import's source files: found inside the TOML file's folder, checked from their headers,
then read one at a time, each check made the same way whether the import writes or only checks.

Each file is handled in two stages. `check_recording` and `check_image` read only headers
(libsndfile's, h5py's dataset shape, Pillow's) and compare them with the description and the
decoding bounds of `acquisition.contracts.media_headers`, so nothing too large is ever decoded.
`_Recording.codes` and `read_image` then read the content and check what only the content
shows (NaN or infinite samples, fewer samples than the header says, the pixel format).
`micam import --check` runs both stages on every file and drops each result at once; the
import runs the same two and writes the result.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import cv2
import numpy as np
import soundfile as sf

from acquisition.contracts.media_headers import (
    UnreadableMedia,
    check_recording_size,
    image_header,
    recording_header,
)
from acquisition.contracts.rig_description import CameraDescription, RigArrayDescription
from acquisition.contracts.session._writer import MAX_CHANNELS

from ._spec import BurstFile, FileRef, ImportSpecError

MAX_IMAGE_BYTES = 256 * 2**20
"""Largest image file read (a 100-megapixel RGB PNG is about this size)."""
HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf")
CODE_FULL_SCALE = 32767


def inside(base: Path, relative: str, where: str) -> Path:
    """`relative` as a regular file inside `base`, refusing anything that leaves it.

    Raises:
        ImportSpecError: an absolute path, a `..`, a link out of `base`, or no such file.
    """
    pure = PurePosixPath(relative)
    if pure.is_absolute() or ".." in pure.parts or not relative.strip() or "\0" in relative:
        raise ImportSpecError(f"{where}: {relative!r} must be a path inside the TOML file's "
                              "folder; write it relative to that folder (no leading '/', no "
                              "'..')")
    path = base / pure
    try:
        leaves = not path.resolve().is_relative_to(base.resolve())
        is_file = path.is_file()
    except OSError as exc:  # a name too long, a loop of links
        raise ImportSpecError(f"{where}: {relative!r} cannot be opened ({exc.strerror}); write "
                              "the path of a file in the TOML file's folder") from None
    if leaves:
        raise ImportSpecError(f"{where}: {relative!r} leads out of the TOML file's folder "
                              "(through a link); copy the file into that folder and write its path")
    if not is_file:
        raise ImportSpecError(f"{where}: {relative!r} does not exist or is not a file (looked "
                              f"for {path}); write the path relative to the TOML file")
    return path


# ---------------------------------------------------------------------------------------------
# Recordings


@dataclass(frozen=True)
class _Recording:
    """A burst recording whose header was checked; `codes` reads and checks its samples."""

    where: str
    path: Path
    start: int
    frames: int
    dataset: str
    source_format: str

    def codes(self) -> tuple[np.ndarray, list[float] | None]:
        """(frames, channels) int16 codes and the per-column scale (None: bit for bit).

        Raises:
            ImportSpecError: the samples cannot be read, are fewer than the header says, or
                hold NaN or infinity.
        """
        name = self.path.name
        try:
            if self.path.suffix.lower() in HDF5_SUFFIXES:
                with _hdf5(self.path, self.where) as f:
                    data = np.asarray(f[self.dataset][self.start:self.start + self.frames])
            else:
                pcm16 = self.source_format.endswith("PCM_16")
                data, _ = sf.read(self.path, start=self.start, frames=self.frames,
                                  dtype="int16" if pcm16 else "float64", always_2d=True)
        except (OSError, RuntimeError) as exc:  # h5py's, libsndfile's (LibsndfileError)
            raise ImportSpecError(f"{self.where}: {name!r} cannot be read past its header "
                                  f"({' '.join(str(exc).split())}); write the path of an "
                                  "intact file") from None
        if data.shape[0] != self.frames:
            raise ImportSpecError(f"{self.where}: {name!r} holds {data.shape[0]} samples from "
                                  f"start_sample {self.start}, its header promised "
                                  f"{self.frames}; the file is truncated: write the path of an "
                                  "intact one")
        if data.dtype == np.int16:
            return np.ascontiguousarray(data), None
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
    """A burst recording checked from its header against the description: it exists, is
    audio at the sample rate, holds the columns read and one burst's samples from its start,
    and is small enough to decode.

    Raises:
        ImportSpecError: naming `where` (the TOML field), the problem and the fix.
    """
    entry = BurstFile(file=ref) if isinstance(ref, str) else ref
    path = inside(base, entry.file, where)
    if path.suffix.lower() in HDF5_SUFFIXES:
        rate, frames, channels, fmt = _hdf5_info(path, entry.dataset, where)
    else:
        try:
            header = recording_header(path)
        except UnreadableMedia as exc:
            raise ImportSpecError(f"{where}: {entry.file!r} is {exc}; convert it to WAV or "
                                  "FLAC and write that file's path") from None
        rate, frames, channels = header.sample_rate_hz, header.frames, header.channels
        fmt = f"{header.container} {header.subtype}"
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
    try:
        check_recording_size(n, channels)
    except UnreadableMedia as exc:
        raise ImportSpecError(f"{where}: {entry.file!r}: one burst's {exc}; split the channels "
                              "into several files, or shorten the burst layout") from None
    return _Recording(where, path, entry.start_sample, n, entry.dataset, fmt)


def _hdf5_info(path: Path, dataset: str, where: str) -> tuple[float, int, int, str]:
    """Sample rate, frames, channels and format of Acoular-style HDF5 time data, from the
    dataset's metadata (nothing is read of its samples)."""
    import h5py

    with _hdf5(path, where) as f:
        link = f.get(dataset, getlink=True)
        if isinstance(link, h5py.ExternalLink):
            raise ImportSpecError(f"{where}: {path.name}:{dataset} is a link into another file "
                                  f"({link.filename}); copy the data into this file")
        ds = f.get(dataset)
        if not isinstance(ds, h5py.Dataset):
            raise ImportSpecError(f"{where}: {path.name} has no dataset {dataset!r}; Acoular "
                                  "writes its time data as 'time_data'; write the dataset's "
                                  "name as dataset = '...'")
        if ds.is_virtual or ds.external:
            raise ImportSpecError(f"{where}: {path.name}:{dataset} keeps its samples in other "
                                  "files; write the path of a file that holds them itself")
        if ds.ndim != 2 or ds.dtype.kind not in "iuf":
            raise ImportSpecError(f"{where}: {path.name}:{dataset} is {ds.dtype} of shape "
                                  f"{ds.shape}; write the name of a dataset of numbers of shape "
                                  "(samples, channels)")
        rate = ds.attrs.get("sample_freq", f.attrs.get("sample_freq"))
        try:
            rate = float(np.asarray(rate, dtype=np.float64).ravel()[0])
        except (TypeError, ValueError, IndexError):
            rate = math.nan
        if not (math.isfinite(rate) and rate > 0):
            raise ImportSpecError(f"{where}: {path.name}:{dataset} has no 'sample_freq' "
                                  "attribute (Acoular's sample rate) holding a positive number; "
                                  "write the rate in Hz into that attribute")
        return rate, int(ds.shape[0]), int(ds.shape[1]), f"HDF5 {ds.dtype}"


# ---------------------------------------------------------------------------------------------
# Images


def check_image(base: Path, relative: str, where: str, camera: CameraDescription) -> Path:
    """An image file checked from its header: inside the folder, of a readable format, of
    the camera's size (so never larger than the decoding bound).

    Raises:
        ImportSpecError: naming `where` (the TOML field), the problem and the fix.
    """
    path = inside(base, relative, where)
    if path.stat().st_size > MAX_IMAGE_BYTES:
        raise ImportSpecError(f"{where}: {relative!r} is larger than {MAX_IMAGE_BYTES} bytes; "
                              "write the path of the camera's own image")
    try:
        header = image_header(path)
    except UnreadableMedia as exc:
        raise ImportSpecError(f"{where}: {relative!r}: {exc}; write the path of the camera's "
                              "own image (PNG, JPEG, TIFF, ...)") from None
    if (header.width, header.height) != (camera.width, camera.height):
        raise ImportSpecError(
            f"{where}: {relative!r} is {header.width} x {header.height} pixels, camera "
            f"{camera.name} is described as {camera.width} x {camera.height}; write its real "
            "size in [[cameras]]")
    return path


def read_image(path: Path, relative: str, where: str, camera: CameraDescription) -> np.ndarray:
    """An image whose header `check_image` passed, decoded as the session stores it (uint8
    grey or BGR).

    Raises:
        ImportSpecError: OpenCV cannot decode it, or its pixels are not 8 or 16 bits.
    """
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or (image.shape[1], image.shape[0]) != (camera.width, camera.height):
        raise ImportSpecError(f"{where}: {relative!r} is not an image OpenCV reads; convert "
                              "it to PNG and write that file's path")
    if image.dtype == np.uint16:
        image = np.rint(image / 257.0).astype(np.uint8)
    if image.dtype != np.uint8 or not (image.ndim == 2 or image.shape[2] in (1, 3, 4)):
        raise ImportSpecError(f"{where}: {relative!r} has {image.dtype} pixels in "
                              f"{1 if image.ndim == 2 else image.shape[2]} channels; write the "
                              "path of an 8- or 16-bit grey or colour image")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    return np.ascontiguousarray(image)
