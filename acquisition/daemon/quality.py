"""Quality checks of each recording and image set: clipping, level, SNR, checkerboard in view.

A recording is judged on the channels that should hear the speaker: the reference microphone
during a reference step, the array's microphones during a pose. Levels are in dBFS (0 dBFS =
the full scale of the channel's range); the SNR compares the power during the burst with the
power of the silence before it (the first `pre_samples` of every recording, before any sound
can arrive). The burst is measured where it arrived, the loudest window of its length after
the silence: it comes late by the path through the air and by the output-to-input latency of
the hardware, microseconds on the boards but milliseconds on an audio interface (longer than
a short burst). Each failed check carries the policy configured for it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from daq import CODE_FULL_SCALE
from kernel.chessboard import quick_look

from .config import Policy, QualityConfig

_FLOOR_DB = -200.0
_MIN_NOISE_SAMPLES = 32
TAIL_SAMPLES = 256
"""A recording whose last samples are within `CUT_DB` of its burst ends inside the burst."""
CUT_DB = 6.0
QUICK_LOOK_PX = 640


@dataclass(frozen=True)
class Levels:
    """Per-channel figures of one recording (arrays of length n_channels)."""

    rms_dbfs: np.ndarray
    peak_dbfs: np.ndarray
    snr_db: np.ndarray | None  # None when the recording has too little silence before the burst
    clipped: list[int]
    delay_samples: int = 0  # how late the burst arrived after it was played (all channels)
    tail_dbfs: np.ndarray | None = None  # RMS of the recording's last TAIL_SAMPLES


@dataclass(frozen=True)
class Failure:
    """A failed check: which, what its policy says to do, and a message for the operator."""

    check: str
    policy: Policy
    message: str


def _db(power_ratio: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.maximum(10.0 * np.log10(power_ratio), _FLOOR_DB)


def burst_arrival(x: np.ndarray, pre_samples: int, burst_samples: int) -> int:
    """The first sample of the loudest `burst_samples` of `x` (n_samples, n_channels) from
    `pre_samples` on, all channels together: where the burst arrived (module docstring)."""
    n = x.shape[0]
    if n - pre_samples <= burst_samples:
        return pre_samples
    energy = np.concatenate([[0.0], np.cumsum((x[pre_samples:] ** 2).sum(axis=1))])
    window = energy[burst_samples:] - energy[:-burst_samples]
    return pre_samples + int(np.argmax(window >= window.max() * (1 - 1e-9)))


def measure(codes: np.ndarray, pre_samples: int, burst_samples: int,
            clip_fraction: float) -> Levels:
    """Levels of raw int16 `codes` (n_samples, n_channels) whose burst is played from
    `pre_samples` on (and arrives at `burst_arrival`)."""
    x = codes.astype(np.float64)
    full = float(CODE_FULL_SCALE)
    start = burst_arrival(x, pre_samples, burst_samples)
    burst = x[start: start + burst_samples]
    peak = np.abs(x).max(axis=0)
    clipped = np.flatnonzero(peak >= clip_fraction * full).tolist()
    if pre_samples >= _MIN_NOISE_SAMPLES:
        noise = x[:pre_samples]
        noise_power = noise.var(axis=0)
        burst_power = ((burst - noise.mean(axis=0)) ** 2).mean(axis=0)
        snr = _db(np.maximum(burst_power - noise_power, 0.0) / np.maximum(noise_power, 1e-12))
    else:
        burst_power = (burst**2).mean(axis=0)
        snr = None
    tail = x[-min(TAIL_SAMPLES, x.shape[0]):]
    return Levels(rms_dbfs=_db(burst_power / full**2), peak_dbfs=_db(peak**2 / full**2),
                  snr_db=snr, clipped=clipped, delay_samples=start - pre_samples,
                  tail_dbfs=_db((tail**2).mean(axis=0) / full**2))


def dead_channels(levels: Levels, mics: Sequence[int], config: QualityConfig) -> list[int]:
    """The microphone columns that hear no burst (SNR below `min_channel_snr_db`)."""
    if levels.snr_db is None:
        return []
    return [m for m in mics if levels.snr_db[m] < config.min_channel_snr_db]


def low_snr_channels(levels: Levels, listening: Sequence[int], dead: Sequence[int],
                     config: QualityConfig) -> list[int]:
    """The listening columns below `min_snr_db` that are not dead (for the operator's eye: the
    check itself judges the median)."""
    if levels.snr_db is None:
        return []
    return [j for j in listening if levels.snr_db[j] < config.min_snr_db and j not in dead]


def judge_recording(levels: Levels, listening: Sequence[int], mics: Sequence[int],
                    check_dead: bool, config: QualityConfig,
                    names: Sequence[str]) -> list[Failure]:
    """The checks a recording fails. `listening`: the columns that should hear the speaker;
    `mics`: the microphone columns, checked for dead channels when `check_dead`; `names`: how
    the messages name each column (`capture_config.column_name`: by microphone id and board
    input, never by column number)."""
    failures = []
    if config.clipping != "ignore" and levels.clipped:
        failures.append(Failure("clipping", config.clipping,
                                f"clipped on {_names(names, levels.clipped)}: move the rig away "
                                "or lower the burst amplitude"))
    level = float(np.median(levels.rms_dbfs[list(listening)]))
    if config.level != "ignore" and level < config.min_level_dbfs:
        failures.append(Failure("level", config.level,
                                f"burst level {level:.1f} dBFS is below {config.min_level_dbfs} "
                                "dBFS: check the speaker, its cable and the amplifier"))
    elif config.level != "ignore" and levels.tail_dbfs is not None and float(np.median(
            levels.tail_dbfs[list(listening)])) > level - CUT_DB:
        failures.append(Failure("level", config.level,
                                "the recording ends before the burst is over (it arrived "
                                f"{levels.delay_samples} samples after it was played: the path "
                                "and the hardware's output-to-input latency): raise "
                                "[hardware.capture.burst] post_samples above that"))
    if levels.snr_db is not None:
        snr = float(np.median(levels.snr_db[list(listening)]))
        if config.snr != "ignore" and snr < config.min_snr_db:
            failures.append(Failure("snr", config.snr,
                                    f"SNR {snr:.1f} dB is below {config.min_snr_db} dB: noise in "
                                    "the room, or the speaker too far away"))
        dead = dead_channels(levels, mics, config)
        if check_dead and config.dead_channels != "ignore" and dead:
            failures.append(Failure("dead_channels", config.dead_channels,
                                    f"no burst heard on {_names(names, dead)} (SNR below "
                                    f"{config.min_channel_snr_db} dB): check those microphones"))
    return failures


def _names(names: Sequence[str], columns: Sequence[int]) -> str:
    return ", ".join(names[j] for j in columns)


def checkerboard_corners(image: np.ndarray, corners: tuple[int, int]) -> np.ndarray | None:
    """The rig's checkerboard corners in `image` (pixels, shape (n, 2)), or None if OpenCV does
    not find all of them; `corners` counts the inner corners, x by y.

    A quick look, not a measurement: the calibration's own quick look (kernel.chessboard), on
    the image shrunk to at most QUICK_LOOK_PX on its longer side (a board partly out of view
    costs OpenCV seconds at full size, a fraction of that shrunk); the corners are not
    refined, calibration refines them from the stored full image.
    """
    scale = min(1.0, QUICK_LOOK_PX / max(image.shape[:2]))
    return quick_look(image, corners, scale).corners_px


def board_outline(corners: np.ndarray, pattern: tuple[int, int], width: int,
                  height: int) -> list[tuple[float, float]]:
    """The four outermost of `corners` (as `checkerboard_corners` returns them, row after row
    of `pattern[0]`) as fractions of the image's `width` and `height`, in order round the
    board."""
    per_row = pattern[0]
    quad = corners[[0, per_row - 1, len(corners) - 1, len(corners) - per_row]]
    return [(round(float(x) / width, 4), round(float(y) / height, 4)) for x, y in quad]


def judge_images(found: Mapping[str, bool], config: QualityConfig) -> list[Failure]:
    """The checkerboard check of a step's images, by camera name."""
    if config.checkerboard == "ignore" or not found:
        return []
    missing = [name for name, ok in found.items() if not ok]
    failed = len(missing) == len(found) if config.checkerboard_in == "any" else bool(missing)
    if not failed:
        return []
    return [Failure("checkerboard", config.checkerboard,
                    f"checkerboard not found in {', '.join(missing)}: hold the whole board in "
                    "view, facing the camera, without glare")]
