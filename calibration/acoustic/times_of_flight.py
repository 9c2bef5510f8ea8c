"""Times of flight of every burst of a session, to every microphone and to the reference
microphone on its stand (paper IV-F, IV-G).

Each pose's six recordings are correlated against the speakers' reference recordings in one
batched call of `calibration.acoustic.delay_estimation.estimate_delays`; a thread per core takes one
pose at a time, so that a 140-pose session never sits in memory whole.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
from scipy import fft as sfft

from acquisition.contracts.step_ids import reference_step

from .._blas import single_threaded_blas
from .._cores import default_workers
from ..memo import LruMemo
from ..session_data import SessionData
from .delay_estimation import TofEstimate, Weighting, estimate_delays, tof_from_delay
from ..levels import ChannelLevels, channel_levels

MAX_RANGE_M = 6.0
"""Longest path searched for a correlation peak; later peaks are reflections."""

TOF_CACHE_POSES = 2_000
"""Poses whose delays a worker's `TofMemo` remembers (about 15 kB each for 73 channels)."""

PoseTofs = tuple[TofEstimate, ChannelLevels]
"""One pose's delays and the levels of the same samples."""

TofMemo = LruMemo[tuple, PoseTofs]
"""A pose's delays and levels by (its recordings' SHA-256, the references' and the
settings): `TofMemo(TOF_CACHE_POSES)`."""


def recording_hashes(data: SessionData, step_of: Callable[[int], str]) -> tuple[str, ...]:
    """SHA-256 of every speaker's recording, speaker k's in step `step_of(k)` (a pose's step
    for all, or each speaker's reference step)."""
    steps = data.reader.steps()
    return tuple(steps[step_of(k)].files[f"speaker_{k}.wav"].sha256
                 for k in range(data.n_speakers))


def _every_speaker_in(step: str) -> Callable[[int], str]:
    """`step` for every speaker (a pose's recordings all belong to its step)."""
    return lambda _speaker: step


def _frozen(pose: PoseTofs) -> PoseTofs:
    """`pose`'s arrays read-only: a memo shares them with every later reader."""
    est, levels = pose
    for array in (est.delay_s, est.std_s, est.snr_db, est.peak_to_sidelobe_db, est.impulses,
                  est.impulse_first_lag, est.echo_energy, est.lead_energy,
                  levels.rail_samples, levels.dropout_share):
        array.flags.writeable = False
    return pose


_PER_MICROPHONE = ("tof_s", "std_s", "snr_db", "peak_to_sidelobe_db", "impulses",
                   "impulse_first_lag", "echo_energy", "lead_energy", "rail_samples",
                   "dropout_share")
"""`SessionTofs`' arrays indexed (pose, speaker, microphone, ...)."""

_MEASURED = ("tof_s", "std_s", "reference_tof_s", "reference_std_s")
"""`SessionTofs`' arrays whose NaN says: left out."""


@dataclass(frozen=True)
class SessionTofs:
    """Times of flight of a session, indexed (pose, speaker, microphone).

    Attributes:
        tof_s: (P, S, M) time of flight from each speaker to each array microphone, seconds
            (it still contains each board's latency relative to the reference microphone's).
        std_s: (P, S, M) predicted standard deviation of each (Cramer-Rao, from the data).
        snr_db: (P, S, M) in-band SNR of each measurement.
        peak_to_sidelobe_db: (P, S, M) correlation peak over its largest sidelobe.
        reference_tof_s: (P, S) time of flight to the reference microphone on its stand
            (NaN when the pose recordings do not hold it).
        reference_std_s: (P, S) its predicted standard deviation (NaN likewise).
        impulses: (P, S, M, n_lag) float32, every array channel's weighted correlation
            around its direct peak (`calibration.acoustic.delay_estimation.TofEstimate.impulses`).
        impulse_first_lag: (P, S, M) full-rate lag (samples) of impulses[..., 0].
        impulse_step: full-rate samples between the impulses' values.
        echo_energy, lead_energy: (P, S, M) every array channel's correlation energy after
            and before its direct peak (`calibration.acoustic.delay_estimation.TofEstimate`).
        rail_samples, dropout_share: (P, S, M) every array channel's samples at the rail and
            share of dropped-out blocks (`calibration.levels.ChannelLevels`).
        polarity: (M,) +1, or -1 for a microphone whose recordings were inverted before the
            correlation (a capsule wired with inverted polarity).
    """

    tof_s: np.ndarray
    std_s: np.ndarray
    snr_db: np.ndarray
    peak_to_sidelobe_db: np.ndarray
    reference_tof_s: np.ndarray
    reference_std_s: np.ndarray
    impulses: np.ndarray
    impulse_first_lag: np.ndarray
    impulse_step: float
    echo_energy: np.ndarray
    lead_energy: np.ndarray
    rail_samples: np.ndarray
    dropout_share: np.ndarray
    polarity: np.ndarray

    def with_microphones(self, kept: np.ndarray) -> SessionTofs:
        """These times of flight of the microphones `kept` (indices into M) alone."""
        per_mic = {name: getattr(self, name)[:, :, kept] for name in _PER_MICROPHONE}
        return replace(self, polarity=self.polarity[kept], **per_mic)

    def with_speakers_from(self, other: SessionTofs, speakers: list[int]) -> SessionTofs:
        """These measurements with those of `speakers` taken from `other` (the same
        recordings correlated again), except where these are NaN: left out already (a
        dropout, a clipped burst), which stays left out."""
        taken = {}
        for name in (*_PER_MICROPHONE, "reference_tof_s", "reference_std_s"):
            mine = getattr(self, name).copy()
            mine[:, speakers] = getattr(other, name)[:, speakers]
            if name in _MEASURED:
                mine = np.where(np.isnan(getattr(self, name)), np.nan, mine)
            taken[name] = mine
        return replace(self, **taken)

    def exchanged(self, a: int, b: int) -> SessionTofs:
        """These measurements with speakers `a`'s and `b`'s exchanged (two speaker cables
        swapped: the recordings made as `a` hold `b`'s bursts)."""
        order = np.arange(self.tof_s.shape[1])
        order[[a, b]] = [b, a]
        return replace(self, **{name: getattr(self, name)[:, order] for name in (
            *_PER_MICROPHONE, "reference_tof_s", "reference_std_s")})

    def echo_ratio(self, poses: list[int] | slice = slice(None)) -> float:
        """The array's correlation energy after the direct sound over that before it, pooled
        over the given poses' measurements: 1 where the recordings hold the direct sound and
        noise alone (free field, flat capsules), far above 1 with reflections or ringing
        capsules; NaN where there is no noise to compare with (no measurement, or silence
        before every direct peak)."""
        echo, lead = self.echo_energy[poses], self.lead_energy[poses]
        kept = np.isfinite(echo) & np.isfinite(lead)  # a dead channel's NaNs say nothing
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(echo[kept].sum() / lead[kept].sum())


def measure_session_tofs(
    data: SessionData,
    speed_of_sound_m_s: float,
    band_hz: tuple[float, float] = (300.0, 20_000.0),
    weighting: Weighting = "compact",
    on_pose: Callable[[str], None] | None = None,
    memo: TofMemo | None = None,
    polarity: np.ndarray | None = None,
    templates: np.ndarray | None = None,
) -> SessionTofs:
    """Times of flight of every pose of `data`.

    `speed_of_sound_m_s` only converts the reference microphone's distance from the speaker
    (about 2 mm, i.e. 6 us) into time, so a value within a few m/s is exact to picoseconds.

    With a `memo`, each pose's delays are remembered by the SHA-256 of its recordings and of
    the references, with the settings (session files never change once written): a
    long-running process, such as the calibration worker whose live jobs see the same poses
    again with a few more each time, correlates every pose once. A remembered pose's files are
    not read again, so the memo's owner answers for them (the worker verified its copies when
    it fetched them); without a memo every recording is read, and checked against the
    journal. Poses are correlated at once on threads (numpy and the FFTs release the
    GIL: 1.5x on two cores): one pose per core, each FFT on its pose's thread.

    `polarity` (M,): +1 or -1 per microphone, the sign its recordings are correlated with
    (None: all +1); the levels do not depend on it.

    `templates` (S,): the speaker whose reference recording each speaker's bursts are
    correlated with (None: its own). A speaker whose own reference recording is spoiled (its
    cable swapped with another's, so the reference microphone heard the other speaker from a
    hand's width away) is measured on a sound speaker's: the same burst through the same
    kind of driver, so its times of flight are right up to a constant, that speaker's
    emission delay relative to the lender's (calibration.solve.bundle fits it).
    """
    on_stand = data.reference_column is not None
    columns = np.append(data.mic_columns, [data.reference_column] if on_stand else [])
    columns = columns.astype(int)
    n_mic = data.mic_columns.size
    signs = np.ones(n_mic) if polarity is None else np.asarray(polarity, dtype=float)
    column_signs = np.append(signs, [1.0] if on_stand else []).astype(np.float32)
    lent = (np.arange(data.n_speakers) if templates is None
            else np.asarray(templates, dtype=int))
    d_ref = data.reference_distances_m[lent, None]  # (S, 1): per speaker, against (S, channels)
    window = (-1e-4, MAX_RANGE_M / speed_of_sound_m_s)
    steady = data.description.burst.steady_window
    if steady is None:
        # one period recorded with silence before and after: zero-padding to a fast FFT
        # length changes nothing but the speed (19 k samples is 19 x 997: a slow length)
        first, stop = 0, data.n_samples
        burst = data.description.burst
        burst_samples: int | None = burst.periods * burst.sequence_samples
        n_fft = sfft.next_fast_len(data.n_samples, real=True)
    else:
        # periodic bursts: the last period holds every arrival in its periodic steady state,
        # and its circular correlation (n_fft = the period) is the periodic impulse response,
        # whose reflections are clean pulses apart from the direct sound's
        first, stop = steady
        n_fft = stop - first
        burst_samples = None
    settings = (band_hz, weighting, window, first, n_fft, tuple(columns.tolist()),
                tuple(signs.tolist()), recording_hashes(data, reference_step),
                tuple(lent.tolist()))
    keys = [(recording_hashes(data, _every_speaker_in(step)), settings)
            for step in data.pose_steps]
    remembered: dict[int, PoseTofs] = {}
    for i, key in enumerate(keys):
        if memo is not None and (known := memo.get(key)) is not None:
            remembered[i] = known
    todo = [i for i in range(len(keys)) if i not in remembered]
    samples = slice(first, stop)
    references = data.references(samples)[lent] if todo else None
    full_scale = data.full_scale() if todo else 1.0

    def correlate(i: int) -> PoseTofs:
        recordings = data.pose_recordings(data.pose_steps[i], columns, samples)
        levels = channel_levels(recordings, full_scale, burst_samples)
        recordings *= column_signs[None, :, None]
        assert references is not None  # read whenever something is to do
        pose = _frozen((estimate_delays(recordings, references, data.fs, band=band_hz,
                                        weighting=weighting, delay_window_s=window,
                                        n_fft=n_fft, fft_workers=1), levels))
        if memo is not None:
            memo.put(keys[i], pose)
        return pose

    # one BLAS thread: the poses' threads already fill the cores, and the band sums'
    # batched products on OpenBLAS's own threads besides made the stage 30 % slower
    with single_threaded_blas(), ThreadPoolExecutor(max_workers=default_workers()) as pool:
        estimates = remembered | dict(zip(todo, pool.map(correlate, todo), strict=True))
    parts = []
    for i, step in enumerate(data.pose_steps):
        est, levels = estimates[i]
        parts.append((tof_from_delay(est.delay_s, d_ref, speed_of_sound_m_s), est.std_s,
                      est.snr_db, est.peak_to_sidelobe_db, est.impulses,
                      est.impulse_first_lag, est.echo_energy, est.lead_energy,
                      levels.rail_samples, levels.dropout_share))
        step_of_lags = est.impulse_step
        if on_pose is not None:
            on_pose(step)
    tof, std, snr, psr, impulses, first_lag, echo, lead, rail, dropout = (
        np.stack(p) for p in zip(*parts, strict=True))
    mics = slice(0, n_mic)
    if on_stand:
        reference_tof, reference_std = tof[..., -1], std[..., -1]
    else:  # no reference microphone in the pose recordings: nothing measured
        reference_tof = np.full(tof.shape[:2], np.nan)
        reference_std = reference_tof.copy()
    return SessionTofs(tof[..., mics], std[..., mics], snr[..., mics], psr[..., mics],
                       reference_tof, reference_std, impulses[:, :, mics],
                       first_lag[:, :, mics], step_of_lags, echo[..., mics], lead[..., mics],
                       rail[..., mics], dropout[..., mics], signs)
