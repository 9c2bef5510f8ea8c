"""Every microphone's complex response (gain and phase against frequency), relative to the
array, from the calibration's own recordings once the geometry is known.

Why: beamforming sums the microphones' signals in phase, so a capsule that lags by half a
microsecond or is 1 dB hot blurs and shifts the map even with a perfect geometry. The bursts
that calibrated the geometry measure the responses too: with every source position, c and
latency fitted, what is left of the transfer from the reference microphone to microphone m,
once its flight is taken out, is m's response (times the reference's, which is common to
all microphones and cancels in a response relative to the array).

Per source s and microphone m, the relative impulse response that the times of flight kept
around the direct peak (the recording with the reference recording deconvolved out) is gated
around its modelled arrival tau_sm (board latency included, the microphone's own delay not;
the gate shorter for higher bands, `GATE_CYCLES`),
transformed, aligned to tau_sm and averaged over each third-octave band b: H_smb, times
L_sm / d_ref (the spreading) and over D_smb, the speaker's piston directivity towards m when
the rig states the speakers' diameter. The mean over sources (room reflections and noise
average out) relative to the array's median gain and mean phase is the response: recorded =
H_mb x ideal. It carries the microphone's own delay (result.json's `delay_s`): apply one or
the other, not both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kernel.air import piston_directivity

from .times_of_flight import SessionTofs

THIRD_OCTAVE_CENTRES_HZ = 10.0 ** (np.arange(30, 43) / 10.0)
"""1 kHz to 16 kHz, the base-10 third-octave centres (above the gate's resolution)."""
GATE_S = 1e-3
"""Longest half-width of the gate around the direct arrival: 1 kHz of resolution; it leaves
out the floor's and the walls' reflections, not those of a table right below the array."""
GATE_CYCLES = 5.0
"""A band's gate spans at most this many periods of its centre frequency either side of the
arrival (a constant-Q gate, as loudspeaker measurements use): 0.3 ms at 16 kHz, which still
resolves a third octave and leaves out a table's reflection 0.35 ms behind the direct sound.
Why: with one 1 ms gate for every band, such a reflection sat inside it, and a capsule's
phase at the top of the band, where it matters most to the dispersion, was the room's (the
140-pose realistic session: 0.0084 mm, 65 % of the microphones' relative geometry within 2
sigma; 0.0076 mm and 82 % with this gate)."""
_FREQUENCIES_PER_BAND = 4
"""Frequencies of each third octave the gated spectrum is averaged over."""
_HALF_BAND = 10.0 ** 0.05
"""A third octave's upper edge over its centre (and its frequencies' widest spread)."""


def dispersion_centres_hz(band_top_hz: float) -> np.ndarray:
    """The bands the capsules' dispersion is measured in, for times of flight correlated up
    to `band_top_hz`: the third octaves of THIRD_OCTAVE_CENTRES_HZ that stay below it, and
    one more whose upper edge is that top.

    Why the top band: a capsule's resonance above the band (25 kHz +- 5 % in the simulated
    lab) bends its phase most in the band's last few kilohertz, and a speaker's directivity
    moves the weight of those kilohertz from source to source. Measured to 16 kHz only, the
    dispersion left each microphone's position along camera 0's axis off in proportion to its
    resonance (correlation 0.78 on the 140-pose session without the room; 0.57 with the top
    band, 0.0076 -> 0.0073 mm on the whole realistic lab)."""
    below = THIRD_OCTAVE_CENTRES_HZ[THIRD_OCTAVE_CENTRES_HZ * _HALF_BAND <= band_top_hz]
    top = band_top_hz / _HALF_BAND
    if below.size and top < below[-1] * 10.0 ** (1.0 / 20.0):  # within a sixth octave
        return below
    return np.append(below, top)
MAX_POSES = 40
"""Poses used at most (evenly spread): 240 sources per microphone average the room out."""


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


def estimate_responses(tofs: SessionTofs, rows: list[int], flights: Flights, fs: float,
                       reference_distances_m: np.ndarray, speed_of_sound_m_s: float,
                       speaker_diameter_m: float | None = None,
                       centres_hz: np.ndarray = THIRD_OCTAVE_CENTRES_HZ,
                       gate_s: float = GATE_S) -> MicrophoneResponses:
    """The microphones' responses (see the module docstring) from the impulses the times of
    flight kept (`SessionTofs.impulses`, rows `rows` of `tofs`, the poses of `flights`).

    Each impulse is gated around the modelled arrival by a Tukey window, +-gate_s or
    `GATE_CYCLES` periods of the band's centre if that is shorter (the room's reflections
    drop out; the gate sets the frequency resolution), and its spectrum taken at
    `_FREQUENCIES_PER_BAND` frequencies of each band (a third octave around its centre). The
    weighting the impulses were correlated with (a window over the band, the reference's
    spectrum) is common to every microphone of a source, so it cancels in responses relative
    to the array.
    """
    step = tofs.impulse_step
    n_lag = tofs.impulses.shape[-1]
    spread = _HALF_BAND ** np.linspace(-1.0, 1.0, _FREQUENCIES_PER_BAND)
    freqs = (centres_hz[:, None] * spread).ravel()  # (n_band x per band,)
    per_source: list[np.ndarray] = []
    # exp(-j w (t - delay)) = exp(-j w (first lag / fs - delay)) exp(-j w n step / fs):
    # one table for the lags, one phasor per measurement and frequency
    lag_table = np.exp(-2j * np.pi * np.outer(step * np.arange(n_lag) / fs, freqs))
    gates = np.repeat(np.minimum(gate_s, GATE_CYCLES / centres_hz), _FREQUENCIES_PER_BAND)
    for i, row in enumerate(rows):
        start = tofs.impulse_first_lag[row] / fs - np.nan_to_num(flights.delay_s[i])
        shift = start[..., None] + step * np.arange(n_lag) / fs  # time from the arrival
        impulses = tofs.impulses[row].astype(np.float64)
        spectrum = np.empty((*impulses.shape[:2], freqs.size), dtype=np.complex128)
        for gate in np.unique(gates):  # the bands that share a gate, in one product
            band = gates == gate
            spectrum[..., band] = (impulses * _tukey(shift / gate)) @ lag_table[:, band]
        spectrum *= np.exp(-2j * np.pi * start[..., None] * freqs)
        H = spectrum.reshape(*spectrum.shape[:2], centres_hz.size, -1).mean(axis=-1)
        H *= (flights.distance_m[i] / np.asarray(reference_distances_m)[:, None])[..., None]
        if speaker_diameter_m:
            H /= np.maximum(piston_directivity(centres_hz, flights.sin_off_axis[i],
                                               speaker_diameter_m / 2, speed_of_sound_m_s),
                            0.05)
        # a measurement the times of flight left out (a clipped or dropped-out recording,
        # a burst not played) says nothing of the microphone's response either
        H[~np.isfinite(tofs.tof_s[row])] = np.nan
        per_source.append(H)
    # masked, not NaN: a microphone without any measurement (dead, or clipped in every
    # burst) gets a NaN response without numpy's warnings about empty slices
    stack = np.ma.masked_invalid(np.concatenate(per_source))  # (n_src, n_mic, n_band)
    n = int(np.sum(stack.count(axis=(1, 2)) > 0))  # sources with a measurement
    stack = stack / np.ma.median(np.ma.abs(stack), axis=1)[:, None]  # each source's own level
    mean = stack.mean(axis=0)
    n_per_mic = stack.count(axis=0)
    reference_gain = np.ma.median(np.ma.abs(mean), axis=0)
    reference_phase = np.ma.angle((mean / np.ma.abs(mean)).sum(axis=0))
    gain = np.ma.abs(mean) / reference_gain
    phase = np.ma.angle(mean * np.exp(-1j * reference_phase))
    relative = stack / mean[None]
    gain_std = gain * np.ma.abs(relative).std(axis=0) / np.sqrt(n_per_mic)
    phase_std = np.ma.angle(relative).std(axis=0) / np.sqrt(n_per_mic)
    gain, phase, gain_std, phase_std = (np.ma.filled(a.astype(float), np.nan)
                                        for a in (gain, phase, gain_std, phase_std))
    return MicrophoneResponses(centres_hz.copy(), gain, phase, gain_std, phase_std, n)


def dispersion_delays(tofs: SessionTofs, responses: MicrophoneResponses, fs: float,
                      gate_s: float = GATE_S) -> np.ndarray:
    """(P, S, M) what each microphone's dispersion did to each of its times of flight, to be
    subtracted from them.

    A capsule whose phase is not linear in frequency (a resonance, a filter) moves the peak of
    a correlation by an amount that depends on that measurement's own spectrum, which the
    speaker's directivity and the room change from source to source: no single delay per
    microphone takes it out. To first order a phase perturbation psi(f) on the correlation
    moves its peak by -sum_f w omega psi / sum_f w omega^2, w the correlation's magnitude. Here
    psi is the microphone's measured phase less its best line through the origin over the
    third octaves to 16 kHz (the line is the microphone's delay, which the joint fit keeps as
    an unknown; a band above them, `dispersion_centres_hz`, is corrected but does not tilt
    the line, so that the delay stays the capsule's group delay below its resonance), and w
    is read from each measurement's own impulse (gated around its peak), band by band.
    """
    f = responses.frequencies_hz
    omega = 2 * np.pi * f
    width = f * (10 ** 0.05 - 10 ** -0.05)  # the bands' widths: the integral's weights
    phase = responses.phase_rad
    line = width * (f <= THIRD_OCTAVE_CENTRES_HZ[-1] * (1 + 1e-9))  # the line's bands
    delay = -np.sum(phase * omega * line, axis=1) / np.sum(omega**2 * line)  # LS line
    psi = phase + omega * delay[:, None]  # (M, n_band): the microphones' dispersion
    n_lag = tofs.impulses.shape[-1]
    t = (np.arange(n_lag) - (n_lag - 1) / 2) * tofs.impulse_step / fs  # centred on the peak
    kernel = _tukey(t / gate_s)[:, None] * np.exp(-2j * np.pi * np.outer(t, f))  # (n_lag, B)
    out = np.zeros(tofs.tof_s.shape)
    for p in range(tofs.impulses.shape[0]):
        w = np.abs(tofs.impulses[p].astype(np.float64) @ kernel) * width  # (S, M, B)
        out[p] = -np.sum(w * omega * psi, axis=-1) / np.sum(w * omega**2, axis=-1)
    return out


def _tukey(u: np.ndarray, flat: float = 0.5) -> np.ndarray:
    """A Tukey window over u in [-1, 1] (zero outside), cosine tapers over the outer
    (1 - flat) of each side."""
    a = np.abs(u)
    edge = (a - flat) / (1.0 - flat)
    return np.where(a <= flat, 1.0, np.where(a < 1.0, 0.5 * (1.0 + np.cos(np.pi * edge)), 0.0))


def evenly_spread(steps: tuple[str, ...] | list[str], n: int = MAX_POSES) -> list[int]:
    """Indices of at most n of `steps`, evenly spread over the session."""
    if len(steps) <= n:
        return list(range(len(steps)))
    return sorted({round(i) for i in np.linspace(0, len(steps) - 1, n)})
