"""Every microphone's complex response (gain and phase against frequency), relative to the
array, from the calibration's own recordings once the geometry is known.

Why: beamforming sums the microphones' signals in phase, so a capsule that lags by half a
microsecond or is 1 dB hot blurs and shifts the map even with a perfect geometry. The bursts
that calibrated the geometry measure the responses too: with every source position, c and
latency fitted, what is left of the transfer from the reference microphone to microphone m,
once its flight is taken out, is m's response (times the reference's, which is common to
all microphones and cancels in a response relative to the array).

Per source s and microphone m, the relative impulse response (the recording with the
reference recording deconvolved out) is gated around its modelled arrival tau_sm (board
latency included, the microphone's own delay not), transformed, aligned to tau_sm and
averaged over each third-octave band b: H_smb, times L_sm / d_ref (the spreading) and over
D_smb, the speaker's piston directivity towards m when the rig states the speakers'
diameter. The mean over sources (room reflections and noise average out) relative to the
array's median gain and mean phase is the response: recorded = H_mb x ideal. It carries the
microphone's own delay (result.json's `delay_s`): apply one or the other, not both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import fft as sfft
from scipy.ndimage import uniform_filter1d
from scipy.signal import windows

from acquisition.air import piston_directivity

from .session_data import SessionData

THIRD_OCTAVE_CENTRES_HZ = 10.0 ** (np.arange(30, 43) / 10.0)
"""1 kHz to 16 kHz, the base-10 third-octave centres (above the gate's resolution)."""
GATE_S = 1e-3
"""Half-width of the gate around the direct arrival: 1 kHz of resolution; it leaves out the
floor's and the walls' reflections, not those of a table right below the array."""
SMOOTHING_HZ = 40.0
"""Width of the moving average of the reference's power spectrum divided out (as the TOFs'
compact weighting: the dips of a burst's spectrum must not amplify the noise)."""
MAX_POSES = 30
"""Poses used at most (evenly spread): 180 sources per microphone average the room out."""


@dataclass(frozen=True)
class Flights:
    """The modelled flight of every source of some poses to every microphone.

    Attributes:
        steps: the pose steps, in session order.
        delay_s: (n_step, n_speaker, n_mic) modelled arrival minus the reference recording's,
            board latency included (the microphone's own delay not).
        distance_m: (n_step, n_speaker, n_mic) distance from the source to the microphone.
        sin_off_axis: (n_step, n_speaker, n_mic) sine of the angle between the speaker's axis
            (the rig's normal) and the direction to the microphone.
    """

    steps: tuple[str, ...]
    delay_s: np.ndarray
    distance_m: np.ndarray
    sin_off_axis: np.ndarray


@dataclass(frozen=True)
class MicrophoneResponses:
    """Relative complex responses of the array's microphones.

    Attributes:
        frequencies_hz: (n_band,) band centres.
        gain: (n_mic, n_band) |H| relative to the array's median.
        phase_rad: (n_mic, n_band) arg H relative to the array's mean (recorded = H x ideal;
            a microphone that lags has a negative phase).
        gain_std, phase_std_rad: their standard errors (scatter over sources / sqrt(n)).
        n_sources: sources averaged.
    """

    frequencies_hz: np.ndarray
    gain: np.ndarray
    phase_rad: np.ndarray
    gain_std: np.ndarray
    phase_std_rad: np.ndarray
    n_sources: int

    def complex(self) -> np.ndarray:
        """(n_mic, n_band) H."""
        return self.gain * np.exp(1j * self.phase_rad)


def estimate_responses(data: SessionData, flights: Flights, reference_distances_m: np.ndarray,
                       speed_of_sound_m_s: float, speaker_diameter_m: float | None = None,
                       centres_hz: np.ndarray = THIRD_OCTAVE_CENTRES_HZ,
                       gate_s: float = GATE_S) -> MicrophoneResponses:
    """The microphones' responses from the poses of `flights` (see the module docstring).

    Each transfer is the reference-deconvolved impulse response gated to +-gate_s around the
    modelled arrival (a Tukey window), so that the room's later reflections drop out; the gate
    sets the frequency resolution (1 / gate_s), so bands far below it are not estimated.
    """
    columns = data.mic_columns
    volts = data.mic_volts_per_unit()
    references = data.references().astype(np.float64)
    n_fft = sfft.next_fast_len(references.shape[-1], real=True)
    X = sfft.rfft(references, n_fft, axis=-1)  # (S, F)
    width = max(1, round(SMOOTHING_HZ * n_fft / data.fs))
    inverse = np.conj(X) / uniform_filter1d(np.abs(X) ** 2, width, axis=-1, mode="nearest")
    half = int(np.ceil(gate_s * data.fs))
    offsets = np.arange(-half, half)
    taper = windows.tukey(offsets.size, 0.5)
    n_gate = sfft.next_fast_len(4 * offsets.size, real=True)
    freqs = np.fft.rfftfreq(n_gate, 1.0 / data.fs)
    edges = centres_hz[:, None] * 10.0 ** (np.array([-1.0, 1.0]) / 20.0)
    in_band = [(freqs >= lo) & (freqs < hi) for lo, hi in edges]
    per_source: list[np.ndarray] = []
    for i, step in enumerate(flights.steps):
        recordings = data.pose_recordings(step)[:, columns, :].astype(np.float64)
        Y = sfft.rfft(recordings * volts[None, :, None], n_fft, axis=-1, workers=-1)
        impulse = sfft.irfft(Y * inverse[:, None, :], n_fft, axis=-1, workers=-1)
        delay = np.nan_to_num(flights.delay_s[i]) * data.fs  # samples
        first = np.floor(delay).astype(np.int64)
        lags = (first[..., None] + offsets) % n_fft
        gated = np.take_along_axis(impulse, lags, axis=-1) * taper
        spectrum = sfft.rfft(gated, n_gate, axis=-1)
        # the segment starts at first - half: put the modelled arrival back at 0
        shift = (first - half - delay)[..., None] / data.fs
        spectrum *= np.exp(-2j * np.pi * freqs * shift)
        H = np.stack([spectrum[..., band].mean(axis=-1) for band in in_band], axis=-1)
        H *= (flights.distance_m[i] / np.asarray(reference_distances_m)[:, None])[..., None]
        if speaker_diameter_m:
            H /= np.maximum(piston_directivity(centres_hz, flights.sin_off_axis[i],
                                               speaker_diameter_m / 2, speed_of_sound_m_s),
                            0.05)
        per_source.append(H)
    stack = np.concatenate(per_source)  # (n_src, n_mic, n_band)
    mean = stack.mean(axis=0)
    n = stack.shape[0]
    reference_gain = np.median(np.abs(mean), axis=0)
    phasors = mean / np.maximum(np.abs(mean), 1e-300)
    reference_phase = np.angle(np.sum(phasors, axis=0))
    gain = np.abs(mean) / reference_gain
    phase = np.angle(mean * np.exp(-1j * reference_phase))
    relative = stack / np.where(mean == 0, 1.0, mean)[None]
    gain_std = gain * np.std(np.abs(relative), axis=0) / np.sqrt(n)
    phase_std = np.std(np.angle(relative), axis=0) / np.sqrt(n)
    return MicrophoneResponses(centres_hz.copy(), gain, phase, gain_std, phase_std, n)


def evenly_spread(steps: tuple[str, ...] | list[str], n: int = MAX_POSES) -> list[int]:
    """Indices of at most n of `steps`, evenly spread over the session."""
    if len(steps) <= n:
        return list(range(len(steps)))
    return sorted({round(i) for i in np.linspace(0, len(steps) - 1, n)})
