"""What each receiver hears from one speaker in the realistic lab, as a transfer function.

The ideal world's propagation is a delay r / c and a 1 / r gain per receiver (`sim.sound.
propagate`). With the lab's effects (sim.lab) every receiver hears the sum of a direct path and
the image sources of the room, each path from the speaker's frequency-dependent acoustic
centre, weighted by the speaker's directivity towards it and the surface's reflection factor.
The transfer function of every (receiver, path) is exact per rFFT bin: the path length
|X - A(f)| is evaluated at each frequency, so nothing is linearised.

Receivers in the near field of the driven speaker (the reference microphone 2 mm in front of
it during a reference recording) hear the diaphragm itself: their direct path is their
distance from the diaphragm, with no acoustic-centre offset and no directivity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kernel.air import piston_directivity

from .lab import LabTruth, RoomModel

REAR_RADIATION = 0.1
"""Amplitude a baffled speaker radiates behind its plate (diffraction around the edges),
relative to on-axis; used for paths that leave the rig backwards."""


@dataclass(frozen=True)
class SpeakerState:
    """One speaker at the moment of a scan.

    Attributes:
        index: the speaker's index on the rig.
        diaphragm_m: (3,) its diaphragm centre, camera-0 frame.
        normal: (3,) unit normal of the rig's printed face (towards the array).
        radius_m: the piston radius (half the stated speaker diameter).
    """

    index: int
    diaphragm_m: np.ndarray
    normal: np.ndarray
    radius_m: float


def _mirror(points: np.ndarray, axis: int, coordinate: float) -> np.ndarray:
    out = np.array(points, dtype=np.float64, copy=True)
    out[..., axis] = 2.0 * coordinate - out[..., axis]
    return out


def _mirror_direction(v: np.ndarray, axis: int) -> np.ndarray:
    out = np.array(v, dtype=np.float64, copy=True)
    out[..., axis] = -out[..., axis]
    return out


def linear_phase(delays_s: np.ndarray, freq_step_hz: float, n_freq: int) -> np.ndarray:
    """(n, n_freq) exp(-j 2 pi k df tau) for k = 0 .. n_freq - 1: a pure delay on the rFFT grid,
    by cumulative products of one exact phasor per delay (one complex multiplication per bin
    instead of an exponential; the rounding grows to about 1e-12 rad over 10^4 bins, i.e.
    1e-17 s of delay)."""
    step = np.exp(-2j * np.pi * freq_step_hz * np.asarray(delays_s, dtype=np.float64))
    out = np.empty((step.size, n_freq), dtype=np.complex128)
    out[:, 0] = 1.0
    if n_freq > 1:
        out[:, 1:] = step[:, None]
        np.cumprod(out[:, 1:], axis=1, out=out[:, 1:])
    return out


_DIRECTIVITY_X = np.linspace(0.0, 60.0, 24_001)
_DIRECTIVITY_TABLE: np.ndarray | None = None


def _directivity(freqs: np.ndarray, sin_theta: np.ndarray, radius_m: float,
                 speed_of_sound_m_s: float) -> np.ndarray:
    """`sim.lab.piston_directivity` from a dense table of 2 J1(x) / x (linear interpolation,
    relative error below 1e-5): the directivity only weights amplitudes."""
    global _DIRECTIVITY_TABLE
    if _DIRECTIVITY_TABLE is None:
        _DIRECTIVITY_TABLE = piston_directivity(np.array([1.0]), _DIRECTIVITY_X, 1.0,
                                                2 * np.pi)[:, 0]
    x = (2 * np.pi * radius_m / speed_of_sound_m_s) * np.outer(np.abs(sin_theta), freqs)
    return np.interp(x, _DIRECTIVITY_X, _DIRECTIVITY_TABLE)


def transfer_functions(lab: LabTruth, room: RoomModel | None, speaker: SpeakerState,
                       receivers_m: np.ndarray, near_field: np.ndarray, freqs_hz: np.ndarray,
                       speed_of_sound_m_s: float, directivity: bool) -> np.ndarray:
    """(n_receivers, n_freq) complex pressure transfer from the speaker to every receiver.

    Per path: (directivity x reflection factor / path length) x exp(-j 2 pi f L(f) / c), with
    L(f) = |X - A(f)| and A(f) the (mirrored) acoustic centre of the speaker at frequency f.
    The direct path's L(f) is exact at every bin; a reflection's uses the acoustic centre at
    the model's reference frequency (a reflection interferes, its sub-millimetre phase does
    not matter). `freqs_hz` must be an rFFT grid (0, df, 2 df, ...). Latency, sensitivity and
    capsule response are the caller's.
    """
    X = np.asarray(receivers_m, dtype=np.float64)
    freqs = np.asarray(freqs_hz, dtype=np.float64)
    df = float(freqs[1] - freqs[0])
    c = speed_of_sound_m_s
    offset = lab.acoustic_offset_m(freqs)[speaker.index]  # (n_freq,)
    ac = lab.effects.acoustic_centres
    offset_ref = float(lab.acoustic_offset_m(np.array([ac.reference_hz if ac else 1.0]))
                       [speaker.index, 0])
    total = np.zeros((X.shape[0], freqs.size), dtype=np.complex128)
    images: list[tuple[np.ndarray, np.ndarray, float, np.ndarray]] = [
        (speaker.diaphragm_m, speaker.normal, 1.0, ~near_field)]
    if room is not None:
        for p, (axis, coordinate, factor) in enumerate(room.planes()):
            source = _mirror(speaker.diaphragm_m, axis, coordinate)
            # where the straight line from the image to each receiver crosses the plane
            denom = X[:, axis] - source[axis]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (coordinate - source[axis]) / denom
            crossing = source + t[:, None] * (X - source)
            valid = (t > 0) & (t < 1) & room.reflection_point_valid(p, crossing)
            images.append((source, _mirror_direction(speaker.normal, axis), factor, valid))
    for k, (source, normal, factor, valid) in enumerate(images):
        rows = np.flatnonzero(valid)
        if rows.size == 0:
            continue
        d = X[rows] - source
        dist2 = np.einsum("ij,ij->i", d, d)
        along = d @ normal  # projection on the normal, > 0 in front of the plate
        L_ref = np.sqrt(dist2 - 2.0 * offset_ref * along + offset_ref**2)
        path = linear_phase(L_ref / c, df, freqs.size) / L_ref[:, None]
        if k == 0 and np.any(offset != offset_ref):
            L = np.sqrt(dist2[:, None] - 2.0 * offset[None, :] * along[:, None]
                        + offset[None, :] ** 2)
            path *= (L_ref[:, None] / L) * np.exp((-2j * np.pi / c) * freqs * (L - L_ref[:, None]))
        if factor != 1.0:
            path *= factor
        if directivity:
            cos_theta = along / np.sqrt(dist2)
            ahead = cos_theta > 0
            sin_theta = np.sqrt(np.maximum(1.0 - cos_theta[ahead] ** 2, 0.0))
            path[ahead] *= _directivity(freqs, sin_theta, speaker.radius_m, c)
            path[~ahead] *= REAR_RADIATION
        if rows.size == X.shape[0]:
            total += path
        else:
            total[rows] += path
    if near_field.any():
        near = np.flatnonzero(near_field)
        r = np.linalg.norm(X[near] - speaker.diaphragm_m, axis=1)
        total[near] += linear_phase(r / c, df, freqs.size) / r[:, None]
    return total
