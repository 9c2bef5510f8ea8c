"""Steering vectors: what a beamformer assumes a source at a scan point sounds like.

Notation: scan point x, microphones m = 1..M at X_m, r_m = |x - X_m|, reference point X_0
(default: the centroid of the microphones), r_0 = |x - X_0|, k = omega / c. With the CSM
convention of `csm` (C_mn = E[p_m p_n*], a delay tau appearing as exp(-i omega tau)), a
monopole of strength s gives p_m = s exp(-i k r_m) / r_m, i.e. the transfer vector relative to
the reference point a_m = (r_0 / r_m) exp(-i k (r_m - r_0)). The beamformer output is

    B(x) = h(x)^H C h(x)

and every formulation here has the form h_m = A_m(x) exp(-i k (r_m - r_0)) with a real,
frequency-independent amplitude A_m (the common phase exp(i k r_0) cancels in B):

=================  ========================================  =====================================
formulation        A_m                                       property (Sarradj 2012)
=================  ========================================  =====================================
classic (I)        1 / M                                     neither level nor location exact
inverse (II)       r_m / (r_0 M)                             neither exact
true level (III)   1 / (r_0 r_m sum_l r_l^-2)                B = S_ss / r_0^2 at the source
true location (IV) 1 / (r_m sqrt(M sum_l r_l^-2))            peak exactly at the source
paper eq. 19       r_m / M                                   = II with r_0 = 1 m (map r_0^2 x II)
paper eq. 20       1 / sqrt(sum_l r_l^-2)                    literal: none of the four
=================  ========================================  =====================================

These are Acoular's four `steer_type`s (acoular 26.8, `SteeringVector`) with identical maps when
the same reference point is used. The paper (Legg & Bradley 2013, eqs 19 and 20) writes
w_m = ... exp(+i omega r_m / c) with b = w^H G w, i.e. its CSM has the transposed orientation
G = E[p* p^T]; its w is our h. Eq. 20 as printed lacks the 1/r_m that would make it
formulation IV (then its map is M times IV's); it is kept literally so that its effect (the
peak is no longer guaranteed at the source) can be shown.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from enum import StrEnum

import numpy as np

from calibration.errors import CalibrationInputError


class Formulation(StrEnum):
    """The steering-vector formulations (see the module docstring for their formulas)."""

    CLASSIC = "classic"
    INVERSE = "inverse"
    TRUE_LEVEL = "true level"
    TRUE_LOCATION = "true location"
    PAPER_EQ19 = "paper eq19"
    PAPER_EQ20 = "paper eq20"


RENORM_STEPS = 32
"""Phase factors advanced by recurrence between equally spaced bins are recomputed exactly
every this many steps (the recurrence's rounding error grows by about 1e-16 per step)."""


def _distances(points: np.ndarray, mics: np.ndarray) -> np.ndarray:
    """|points[g] - mics[m]| (G, M), one coordinate at a time (no (G, M, 3) temporary)."""
    total = np.zeros((points.shape[0], mics.shape[0]))
    for axis in range(3):
        d = points[:, axis, None] - mics[None, :, axis]
        d *= d
        total += d
    return np.sqrt(total, out=total)


def unit_phasors(angle: np.ndarray) -> np.ndarray:
    """exp(-i angle) in complex128 for float64 angles, to about 1e-15, faster than
    np.exp on this workload (benchmarks/bench_imaging.py): the angle is reduced to [-pi, pi],
    halved k times until it is
    below 0.1, the Taylor series of cos and sin taken to the 10th and 11th order (error
    < 3e-18) and the result squared k times."""
    x = np.array(angle, dtype=np.float64, copy=True)
    top = float(np.max(np.abs(x))) if x.size else 0.0
    if top > np.pi:
        turns = x * (1 / (2 * np.pi))
        np.rint(turns, out=turns)
        turns *= 2 * np.pi
        x -= turns
        top = np.pi
    halvings = max(int(np.ceil(np.log2(top / 0.1))), 0) if top > 0 else 0
    x *= 0.5**halvings
    y2 = x * x
    z = np.empty_like(x, dtype=np.complex128)
    c, s = z.real, z.imag
    # cos y = 1 - y^2/2 (1 - y^2/12 (1 - y^2/30 (1 - y^2/56 (1 - y^2/90))))
    np.multiply(y2, -1 / 90, out=c)
    for k in (56, 30, 12, 2):
        c += 1.0
        c *= y2
        c *= -1 / k
    c += 1.0
    # -sin y = -y (1 - y^2/6 (1 - y^2/20 (1 - y^2/42 (1 - y^2/72 (1 - y^2/110)))))
    np.multiply(y2, -1 / 110, out=s)
    for k in (72, 42, 20, 6):
        s += 1.0
        s *= y2
        s *= -1 / k
    s += 1.0
    s *= x
    np.negative(s, out=s)
    for _ in range(halvings):
        np.multiply(z, z, out=z)
    return z


def _power(z: np.ndarray, n: int) -> np.ndarray:
    """z**n elementwise for a positive integer n, by repeated squaring."""
    if n < 1:
        raise ValueError(f"the power must be a positive integer, not {n}")
    result: np.ndarray | None = None
    square = z.copy(order="K")
    while True:
        if n & 1:
            if result is None:
                result = square.copy(order="K")
            else:
                np.multiply(result, square, out=result)
        n >>= 1
        if not n:
            assert result is not None  # n >= 1 has a set bit, met before n reaches 0
            return result
        np.multiply(square, square, out=square)


def _as_points(points: np.ndarray, what: str) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0:
        raise ValueError(f"{what} must be a non-empty (n, 3) array of positions in metres, "
                         f"got shape {p.shape}")
    return p


class SteeringModel:
    """Steering vectors of a set of scan points for one array, at any frequency.

    The distances and amplitudes are computed on first use and kept; `vectors(f)` then costs
    one complex exponential per (point, microphone), and `vectors_at(freqs)` advances equally
    spaced bins by a complex multiplication instead. `block(start, stop)` is the model of a
    contiguous range of the points (for cache-sized, parallel work).

    Args:
        points: (G, 3) scan points, metres, in the frame of the microphones.
        mics: (M, 3) microphone positions, metres.
        speed_of_sound_m_s: c.
        formulation: one of `Formulation`.
        reference: X_0, the point levels are referred to (II, III); default the centroid of
            the microphones. Acoular's default is the origin of its frame.
        latencies_s: (M,) extra delay of each microphone's channel (e.g. the calibrated board
            latencies), seconds: the phase becomes exp(-i k (r_m + c tau_m - r_0)). Only
            differences between channels matter.
    """

    def __init__(self, points: np.ndarray, mics: np.ndarray, speed_of_sound_m_s: float,
                 formulation: Formulation | str = Formulation.TRUE_LOCATION,
                 reference: np.ndarray | None = None,
                 latencies_s: np.ndarray | None = None) -> None:
        self.points = _as_points(points, "scan points")
        self.mics = _as_points(mics, "microphone positions")
        if not speed_of_sound_m_s > 0:
            raise ValueError(f"speed of sound {speed_of_sound_m_s} m/s must be positive")
        self.c = float(speed_of_sound_m_s)
        self.formulation = Formulation(formulation)
        self.reference = (self.mics.mean(axis=0) if reference is None
                          else np.asarray(reference, dtype=np.float64).reshape(3))
        self.latencies_s = None
        if latencies_s is not None:
            tau = np.asarray(latencies_s, dtype=np.float64)
            if tau.shape != (self.n_mics,):
                raise ValueError(f"latencies must be one per microphone ({self.n_mics}), got "
                                 f"shape {tau.shape}")
            self.latencies_s = tau
        self._geometry: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def __getstate__(self) -> dict:
        """Pickled without the computed arrays (G x M each): cheaper to recompute than to
        ship to another process."""
        return {**self.__dict__, "_geometry": None}

    def _computed(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(distances r_m, path differences r_m - r_0 + c tau_m, amplitudes A_m), each (G, M)."""
        if self._geometry is None:
            r = _distances(self.points, self.mics)
            if np.any(r < 1e-9):
                raise CalibrationInputError(
                    "a scan point coincides with a microphone: move the scan "
                    "surface off the array")
            r0 = np.linalg.norm(self.points - self.reference, axis=1)
            path = r - r0[:, None]
            if self.latencies_s is not None:
                path += self.c * self.latencies_s
            self._geometry = (r, path, amplitudes(self.formulation, r, r0))
        return self._geometry

    @property
    def distances(self) -> np.ndarray:
        """|x - X_m| (G, M), metres."""
        return self._computed()[0]

    @property
    def path_difference(self) -> np.ndarray:
        """r_m - r_0 + c tau_m (G, M), metres: the phase is -k times this."""
        return self._computed()[1]

    @property
    def amplitude(self) -> np.ndarray:
        """A_m (G, M), the formulation's real amplitudes."""
        return self._computed()[2]

    def block(self, start: int, stop: int) -> SteeringModel:
        """The model of points[start:stop]: slices of this one's arrays if they are computed,
        else computed for those points only."""
        part = copy.copy(self)
        part.points = self.points[start:stop]
        if self._geometry is not None:
            r, path, amplitude = self._geometry
            part._geometry = (r[start:stop], path[start:stop], amplitude[start:stop])
        return part

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_mics(self) -> int:
        return int(self.mics.shape[0])

    def wavenumber(self, freq_hz: float) -> float:
        return 2.0 * np.pi * float(freq_hz) / self.c

    def vectors(self, freq_hz: float) -> np.ndarray:
        """(G, M) complex128 steering vectors h at freq_hz."""
        h = unit_phasors(self.wavenumber(freq_hz) * self.path_difference)
        h *= self.amplitude
        return h

    def _vectors_single_trig(self, freq_hz: float) -> np.ndarray:
        """(G, M) complex64 steering vectors, accurate to about 3e-7.

        The phase k (r_m - r_0) is computed and reduced to [-pi, pi] in float64; only the
        reduced angle is rounded to float32 and its cosine and sine are taken in float32
        (absolute phase error <= 3e-7 rad; Acoular rounds the unreduced k r, about 150 rad at
        8 kHz and 1 m, to float32: up to 8e-6 rad). Much faster than the float64
        exponential (benchmarks/bench_imaging.py).
        """
        cycles = self.path_difference * (float(freq_hz) / self.c)
        cycles -= np.rint(cycles)
        angle = cycles.astype(np.float32)
        angle *= np.float32(2.0 * np.pi)
        amplitude = self.amplitude.astype(np.float32)
        h = np.empty_like(angle, dtype=np.complex64)
        np.multiply(amplitude, np.cos(angle), out=h.real)
        np.sin(angle, out=angle)
        amplitude *= angle
        np.negative(amplitude, out=h.imag)
        return h

    def _step_single(self, df_hz: float) -> np.ndarray:
        """exp(-i k(df) (r_m - r_0)) (G, M) complex128 for the complex64 path: the small
        angle (|k(df)| (r_m - r_0) ~ 0.06 rad for 23 Hz bins and a 0.15 m array) in float32
        trigonometry, the modulus then made 1 to second order in float64. Error about 1e-8
        per step (9e-9 measured), so 2e-7 after 20 bins: below the first bin's 3e-7."""
        angle = (self.wavenumber(df_hz) * self.path_difference).astype(np.float32)
        z = np.empty_like(angle, dtype=np.complex128)
        np.cos(angle, out=z.real, casting="unsafe")
        np.sin(angle, out=z.imag, casting="unsafe")
        norm = z.real * z.real
        norm += z.imag * z.imag
        norm *= -0.5
        norm += 1.5  # 1 / |z| to second order in |z|^2 - 1 (about 1e-7 here)
        z.real *= norm
        norm *= -1.0
        z.imag *= norm
        return z

    def vectors_at(self, freqs_hz: np.ndarray, dtype: type = np.complex128,
                   shared: bool = False) -> Iterator[np.ndarray]:
        """Steering vectors (G, M) for each frequency in turn, as `dtype`.

        Between equally spaced frequencies h(f + df) = h(f) * exp(-i k(df) (r_m - r_0)): one
        complex multiplication instead of an exponential, recomputed exactly every
        `RENORM_STEPS` steps. With dtype=complex128 the recurrence runs in complex128 on phases
        computed in float64. With dtype=complex64 it runs in complex64 (half the memory
        traffic); the exact recomputations use `_vectors_single_trig` (phase error at most about
        3e-7 rad, against Acoular's 8e-6 at 8 kHz) and the step `_step_single`, so the yielded
        vectors stay within about 2e-6 of `vectors(f)` (relative to their largest element), and
        the beamforming maps within 7e-7 per bin of the float64 maps over the 20 bins of the
        benchmark.

        Each yielded array belongs to the caller, unless `shared`: then it is the generator's
        own state, read-only and valid until the next bin (it is advanced in place), which
        saves allocating and writing a new (G, M) array per bin.
        """
        freqs = np.asarray(freqs_hz, dtype=np.float64).ravel()
        single = np.dtype(dtype) == np.complex64
        if not single and np.dtype(dtype) != np.complex128:
            raise ValueError(f"steering vectors are complex64 or complex128, not {dtype}")
        if freqs.size == 0:
            return

        def exact(f: float) -> np.ndarray:
            return self._vectors_single_trig(f) if single else self.vectors(f)

        step: tuple[float, np.ndarray] | None = None
        state = None
        if not single and freqs.size > 1:
            # FFT bins: f_0 = n_0 df with an integer n_0, so h(f_0) = A u^n_0 with u the step
            # exp(-i k(df) (r_m - r_0)); u^n_0 by repeated squaring (about log2(n_0) + 2
            # complex products) costs a third of a float64 exponential, with a relative error
            # of about n_0 x 1e-16 (3e-14 at 8 kHz).
            df = freqs[1] - freqs[0]
            n0 = round(freqs[0] / df) if df > 0 else 0
            if 0 < n0 <= 4096 and abs(freqs[0] - n0 * df) <= 1e-12 * freqs[0]:
                step = (df, unit_phasors(self.wavenumber(df) * self.path_difference))
                state = _power(step[1], n0)
                state *= self.amplitude
        if state is None:
            # In complex64 the recurrence runs in complex64 too: half the memory traffic, and
            # its rounding (about 6e-8 per step, RENORM_STEPS at most) stays far below 1e-5.
            state = exact(freqs[0])
        since_exact = 0
        for i in range(freqs.size):
            if shared:
                state.flags.writeable = False
                yield state
                state.flags.writeable = True
            else:
                yield state  # the next state is a new array
            if i + 1 == freqs.size:
                return
            f, df = freqs[i + 1], freqs[i + 1] - freqs[i]
            if since_exact + 1 >= RENORM_STEPS:
                state = exact(f)
                since_exact = 0
                continue
            if step is None or abs(df - step[0]) > 1e-9 * max(abs(f), 1.0):
                step = (df, self._step_single(df).astype(np.complex64) if single else
                        unit_phasors(self.wavenumber(df) * self.path_difference))
            if shared:
                state *= step[1]
            else:
                state = state * step[1]
            since_exact += 1


def amplitudes(formulation: Formulation, r: np.ndarray, r0: np.ndarray) -> np.ndarray:
    """The real amplitudes A_m (G, M) of a formulation, from distances r (G, M) and r0 (G,)."""
    m = r.shape[1]
    inverse = 1.0 / r
    inv_sq = np.einsum("gm,gm->g", inverse, inverse)[:, None]
    r0 = r0[:, None]
    if formulation is Formulation.CLASSIC:
        return np.full(r.shape, 1.0 / m)
    if formulation is Formulation.INVERSE:
        return r / (r0 * m)
    if formulation is Formulation.TRUE_LEVEL:
        return 1.0 / (r0 * r * inv_sq)
    if formulation is Formulation.TRUE_LOCATION:
        return inverse * (1.0 / np.sqrt(m * inv_sq))
    if formulation is Formulation.PAPER_EQ19:
        return r / m
    return np.broadcast_to(1.0 / np.sqrt(inv_sq), r.shape).copy()
