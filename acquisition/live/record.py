"""A live recording on disk: the session format, and Acoular's HDF5 time-data layout beside it.

`write_live_recording` stores the latest seconds of a live scan as a session (the contract of
docs/session-format.md) of one step, `live`, holding `live.wav` (every column's raw int16
codes, the capture configuration naming each column as for any session) and every camera
frame taken during it (`<camera>-<k>.png`, k = 0000, 0001, ..., each with the stream index it
was taken at in its metadata, `sample`; the recording's own first index is `first_sample` in
the metadata of live.wav); the session is closed as complete at once. Beside the journal,
`time_data.h5` holds the microphones' time data as Acoular reads it
(`acoular.TimeSamples(file=...)`): one dataset `time_data`, float32 volts shaped (samples,
channels) with the microphones in the order of their ids (the order of `micam calibrate
--acoular-xml`), and the attribute `sample_freq` (hertz). Its attribute `mic_ids` lists the
ids; the reference microphone is left out.

The HDF5 file is written to a temporary name, flushed and renamed, like every session file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.session import SessionError, SessionReader, SessionWriter
from .ring import StampedFrame

STEP = "live"
RECORDING = "live.wav"
ACOULAR_FILE = "time_data.h5"


def frame_name(camera: str, k: int) -> str:
    """The file name of camera frame k of a live recording."""
    return f"{camera}-{k:04d}.png"


def read_live_recording(path: Path, camera: str
                        ) -> tuple[np.ndarray, int, int, list[StampedFrame], CaptureConfig]:
    """A live recording: its codes (n, columns), sample rate, first stream index, the frames
    of `camera` (oldest first) and its capture configuration. Raises SessionError saying what
    is wrong."""
    reader = SessionReader(path)
    config = CaptureConfig.of_session(reader.capture, path)
    step = reader.steps().get(STEP)
    if step is None:
        raise SessionError(f"{path} is not a live recording (it has no step {STEP!r})")
    codes, fs = reader.read_recording(STEP, RECORDING)
    first = int(step.files[RECORDING].meta.get("first_sample", 0))
    names = sorted(n for n in step.files if n.startswith(f"{camera}-") and n.endswith(".png"))
    frames = [StampedFrame(camera, int(step.files[n].meta["sample"]),
                           reader.read_image(STEP, n)) for n in names]
    return codes, fs, first, frames, config


def mic_volts(codes: np.ndarray, config: CaptureConfig) -> tuple[np.ndarray, list[int]]:
    """The microphone columns of `codes` in volts (n, M) float32, sorted by microphone id,
    and the ids."""
    mics = sorted((c.mic_id, j, c.range_v) for j, c in enumerate(config.columns)
                  if c.role == "mic" and c.mic_id is not None)
    if not mics:
        raise SessionError("the capture configuration names no microphone column")
    columns = [j for _, j, _ in mics]
    scale = np.array([r / 32768.0 for _, _, r in mics], dtype=np.float32)
    return codes[:, columns].astype(np.float32) * scale, [m for m, _, _ in mics]


def write_acoular_h5(path: Path, volts: np.ndarray, sample_rate_hz: float,
                     mic_ids: list[int]) -> None:
    """Acoular's time-data file (module docstring), written atomically."""
    import h5py

    partial = path.with_name(path.name + ".partial")
    with h5py.File(partial, "w") as f:
        data = f.create_dataset("time_data", data=np.ascontiguousarray(volts, np.float32))
        data.attrs["sample_freq"] = float(sample_rate_hz)
        data.attrs["mic_ids"] = np.asarray(mic_ids, dtype=np.int64)
        f.flush()
    with open(partial, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(partial, path)


def write_live_recording(path: Path, config: CaptureConfig, codes: np.ndarray,
                         first_sample: int, frames: list[StampedFrame],
                         session_id: str | None = None) -> Path:
    """Store a live recording (module docstring) in the new directory `path`; returns it.

    Args:
        config: the capture configuration (columns, sample rate).
        codes: (n, columns) int16 codes, the columns of `config`.
        first_sample: the stream index of the first row (kept in the recording's metadata).
        frames: the camera frames taken during the recording.
    """
    if codes.ndim != 2 or codes.shape[1] != len(config.columns) or codes.shape[0] == 0:
        raise ValueError(f"a live recording needs (n, {len(config.columns)}) codes, got "
                         f"{codes.shape}")
    fs = config.sample_rate_hz
    writer = SessionWriter.create(path, config.model_dump(mode="json"), session_id)
    try:
        writer.begin_step(STEP)
        writer.write_recording(STEP, RECORDING, codes, round(fs),
                               meta={"first_sample": int(first_sample)})
        counts: dict[str, int] = {}
        for frame in frames:
            k = counts[frame.camera] = counts.get(frame.camera, -1) + 1
            writer.write_image(STEP, frame_name(frame.camera, k), frame.image,
                               meta={"sample": int(frame.sample)})
        writer.end_step(STEP)
        volts, ids = mic_volts(codes, config)
        write_acoular_h5(Path(path) / ACOULAR_FILE, volts, fs, ids)
        writer.stop("success")
    except BaseException:
        writer.close()
        raise
    return Path(path)
