"""What a recording's samples say about its channel, beside the times of flight: clipping
and dropouts.

Both are read from the same samples the correlation reads (a pose's recordings are read
once, `calibration.acoustic.times_of_flight`), and both are facts of the waveform that no
correlation shows: a clipped burst still correlates, its peak a little off; a burst with a gap still
correlates, on less signal than its predicted precision assumes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RAIL_SHARE = 0.5
"""A recording is clipped only where its extreme value is at least this share of the
channel's full scale: a quiet channel reaches its own small maximum often, by quantisation."""

CLIPPED_SAMPLES = 8
"""Samples at the rail from which a recording counts as clipped: an unclipped burst reaches
its exact peak code once or twice, a clipped one for a run of samples at each crest."""

DROPOUT_BLOCK = 256
"""Samples per block of the dropout test (2.7 ms at 96 kS/s: a dropout of a loose contact
lasts tens of milliseconds, an MLS's envelope is flat over a block)."""

DROPOUT_DB = 20.0
"""A block this far below the recording's median block level (dB) has dropped out: an MLS
played into a room varies by a few dB from block to block, a channel at idle noise by the
whole signal-to-noise ratio."""


@dataclass(frozen=True)
class ChannelLevels:
    """Per (speaker, channel) facts of one pose's recordings.

    Attributes:
        rail_samples: (S, C) samples at the rail: at the recording's extreme absolute value,
            where that value is at least `RAIL_SHARE` of full scale (0 elsewhere).
        dropout_share: (S, C) share of the blocks of the burst as the channel heard it (from
            its first block within `DROPOUT_DB` of its loudest to its last) that lie more
            than `DROPOUT_DB` below the median of those blocks. An MLS is a constant level
            while it plays, so a quiet block inside it is a channel that went to idle noise.
    """

    rail_samples: np.ndarray
    dropout_share: np.ndarray


def channel_levels(recordings: np.ndarray, full_scale: float,
                   burst_samples: int | None = None) -> ChannelLevels:
    """The levels of (S, C, n) `recordings` in codes whose full scale is `full_scale` codes
    (a burst's steady period, or a whole recording with silence around its burst).

    `burst_samples`: how long the burst lasts, for a recording with silence around it: the
    dropout test then looks at the blocks the direct sound alone fills, from the first block
    it reaches. A short burst in a room leaves a quiet gap before a late reflection as loud
    as itself, which is no dropout (an MLS of order 10, 10.7 ms at 96 kS/s: 18 of 48
    microphones flagged in a clean 3-pose realistic session). None: the recordings are one
    steady period of a continuing burst, every block inside it."""
    magnitude = np.abs(recordings)
    peak = magnitude.max(axis=-1)
    at_rail = (magnitude >= peak[..., None]).sum(axis=-1)
    rail = np.where(peak >= RAIL_SHARE * full_scale, at_rail, 0)
    n_blocks = recordings.shape[-1] // DROPOUT_BLOCK
    blocks = recordings[..., :n_blocks * DROPOUT_BLOCK].reshape(
        *recordings.shape[:-1], n_blocks, DROPOUT_BLOCK)
    power = np.mean(np.square(blocks, dtype=np.float64), axis=-1)
    below = 10.0 ** (-DROPOUT_DB / 10.0)
    loud = power >= below * power.max(axis=-1, keepdims=True)
    index = np.arange(n_blocks)
    first = np.argmax(loud, axis=-1)[..., None]
    last = (n_blocks - 1 - np.argmax(loud[..., ::-1], axis=-1))[..., None]
    if burst_samples is not None:  # the blocks the burst fills whole, wherever it starts
        last = np.minimum(last, first + max(1, burst_samples // DROPOUT_BLOCK) - 1)
    heard = np.where((index >= first) & (index <= last), power, np.nan)
    median = np.nanmedian(heard, axis=-1, keepdims=True)
    quiet = np.sum(heard < below * median, axis=-1)
    return ChannelLevels(rail, quiet / np.sum(np.isfinite(heard), axis=-1))


def full_scale_of(codes: np.ndarray) -> float:
    """The full scale, in codes, of a recording read as `codes`: 2**15 for 16-bit integers,
    2**31 for 32-bit ones (24-bit files are read into them), 1 for floating-point samples."""
    if np.issubdtype(codes.dtype, np.integer):
        return float(np.iinfo(codes.dtype).max) + 1.0
    return 1.0
