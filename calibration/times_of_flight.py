"""Times of flight of every burst of a session, to every microphone and to the reference
microphone on its stand (paper IV-F, IV-G).

Each pose's six recordings are correlated against the speakers' reference recordings in one
batched call of `calibration.tof.estimate_delays`; poses are processed one at a time so that a
140-pose session never sits in memory whole.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import fft as sfft

from .session_data import SessionData
from .tof import estimate_delays, tof_from_delay

MAX_RANGE_M = 6.0
"""Longest path searched for a correlation peak; later peaks are reflections."""


@dataclass(frozen=True)
class SessionTofs:
    """Times of flight of a session, indexed (pose, speaker, microphone).

    Attributes:
        tof_s: (P, S, M) time of flight from each speaker to each array microphone, seconds
            (it still contains each board's latency relative to the reference microphone's).
        std_s: (P, S, M) predicted standard deviation of each (Cramer-Rao, from the data).
        snr_db: (P, S, M) in-band SNR of each measurement.
        peak_to_sidelobe_db: (P, S, M) correlation peak over its largest sidelobe.
        reference_tof_s: (P, S) time of flight to the reference microphone on its stand.
        reference_std_s: (P, S) its predicted standard deviation.
    """

    tof_s: np.ndarray
    std_s: np.ndarray
    snr_db: np.ndarray
    peak_to_sidelobe_db: np.ndarray
    reference_tof_s: np.ndarray
    reference_std_s: np.ndarray


def measure_session_tofs(
    data: SessionData,
    speed_of_sound_m_s: float,
    band_hz: tuple[float, float] = (300.0, 20_000.0),
    phat: bool = False,
    on_pose: Callable[[str], None] | None = None,
) -> SessionTofs:
    """Times of flight of every pose of `data`.

    `speed_of_sound_m_s` only converts the reference microphone's distance from the speaker
    (about 2 mm, i.e. 6 us) into time, so a value within a few m/s is exact to picoseconds.
    """
    references = data.references()
    columns = np.append(data.mic_columns, data.reference_column)
    d_ref = data.config.reference.distance_from_speaker_m
    window = (-1e-4, MAX_RANGE_M / speed_of_sound_m_s)
    # Bursts are recorded with silence before and after, so zero-padding to a fast FFT length
    # changes nothing but the speed (19 k samples is 19 x 997: a slow length).
    n_fft = sfft.next_fast_len(references.shape[1], real=True)
    parts = []
    for step in data.pose_steps:
        recordings = data.pose_recordings(step)[:, columns, :]
        est = estimate_delays(recordings, references, data.fs, band=band_hz, phat=phat,
                              delay_window_s=window, n_fft=n_fft)
        parts.append((tof_from_delay(est.delay_s, d_ref, speed_of_sound_m_s), est.std_s,
                      est.snr_db, est.peak_to_sidelobe_db))
        if on_pose is not None:
            on_pose(step)
    tof, std, snr, psr = (np.stack(p) for p in zip(*parts, strict=True))
    return SessionTofs(tof[..., :-1], std[..., :-1], snr[..., :-1], psr[..., :-1],
                       tof[..., -1], std[..., -1])
