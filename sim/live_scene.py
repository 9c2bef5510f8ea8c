"""Sound sources that play continuously and move, for the live acoustic view.

A `LiveScene` is a set of sources in the world's air: a tone (a speaker carried along a path,
or two speakers at different frequencies) or white noise (a broadband noise source), each on
a `Trajectory` (waypoints in time, camera-0 frame; a single waypoint stands still). It gives
the voltage of every array microphone for any range of sample indices of a continuous scan,
always the same samples for the same indices whatever the read pattern (the board reads of a
live scan come in any block sizes), with the world's microphone gains, board latencies and
speed of sound; the bench (`AcousticBench.play_scene`) adds the input noise and quantisation.

Propagation, for a source at x_s(t) and microphone m at X_m: the level falls as 1/r (the
source's `rms_v_at_1m` is the RMS voltage it gives a microphone of unit gain 1 m away) and the
sound is delayed by r/c plus the board latency. A tone is evaluated exactly at every sample
with the source where it is at that sample's time (its phase, Doppler shift included, is then
continuous as the source moves). Noise is delayed by a linear phase in the frequency domain,
on chunks of `CHUNK_SAMPLES` with the source where it is at the chunk's centre (at 1 m/s it
moves 4 cm in a chunk; the noise is incoherent from one chunk to the next anyway) and
`MARGIN_SAMPLES` of signal either side, which makes the circular delay's error at the chunk
about 1e-3 of the signal (-60 dB, below the microphones' own noise).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.fft

from .world import World

CHUNK_SAMPLES = 4096
"""Samples rendered at a time (and cached), aligned on multiples of this."""
MARGIN_SAMPLES = 512
"""Signal taken beyond each end of a noise chunk for its circular delay."""
KNOT_SAMPLES = 256
"""A moving tone's distances are computed every this many samples, linear in between."""
CACHED_CHUNKS = 8
"""Rendered chunks kept: every board of a scan reads the same samples."""


@dataclass(frozen=True)
class Trajectory:
    """Where a source is: waypoints (K, 3) in the camera-0 frame at times (K,) seconds from
    the scan's start, linear in between, held before the first and after the last; with
    `period_s`, the path starts again every period_s (for a scan without end)."""

    waypoints_m: np.ndarray
    times_s: np.ndarray = field(default_factory=lambda: np.zeros(1))
    period_s: float | None = None

    def __post_init__(self) -> None:
        p = np.asarray(self.waypoints_m, dtype=np.float64).reshape(-1, 3)
        t = np.asarray(self.times_s, dtype=np.float64).ravel()
        if p.shape[0] != t.size or t.size == 0:
            raise ValueError(f"a trajectory needs one time per waypoint, got {p.shape[0]} "
                             f"waypoints and {t.size} times")
        if np.any(np.diff(t) <= 0):
            raise ValueError("trajectory times must increase")
        if self.period_s is not None and not self.period_s > t[-1]:
            raise ValueError(f"a trajectory's period {self.period_s} s must exceed its last "
                             f"time {t[-1]} s")
        object.__setattr__(self, "waypoints_m", p)
        object.__setattr__(self, "times_s", t)

    @staticmethod
    def still(position_m: Sequence[float]) -> Trajectory:
        return Trajectory(np.asarray(position_m, dtype=np.float64).reshape(1, 3))

    def at(self, t_s: np.ndarray | float) -> np.ndarray:
        """Positions (..., 3) at times t_s."""
        t = np.asarray(t_s, dtype=np.float64)
        if self.period_s is not None:
            t = np.mod(t, self.period_s)
        return np.stack([np.interp(t, self.times_s, self.waypoints_m[:, k]) for k in range(3)],
                        axis=-1)


@dataclass(frozen=True)
class LiveSource:
    """One source: a tone of `frequency_hz` or, with frequency_hz None, white noise.

    Attributes:
        trajectory: where it is.
        rms_v_at_1m: RMS voltage at a microphone of unit gain 1 m away.
        frequency_hz: the tone's frequency, or None for broadband (white) noise.
        seed: the noise's seed (with the world's).
    """

    trajectory: Trajectory
    rms_v_at_1m: float = 0.05
    frequency_hz: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if not self.rms_v_at_1m >= 0:
            raise ValueError(f"a source's level {self.rms_v_at_1m} V must be >= 0")
        if self.frequency_hz is not None and not self.frequency_hz > 0:
            raise ValueError(f"a tone's frequency {self.frequency_hz} Hz must be positive")


class LiveScene:
    """The microphone voltages of continuously playing sources (module docstring)."""

    def __init__(self, world: World, sources: Sequence[LiveSource]) -> None:
        self.world = world
        self.sources = tuple(sources)
        layout = world.layout
        self._mics = layout.mic_positions_m
        self._latency = world.board_latencies_s[[r.board for r in layout.mic_inputs]]
        self._gain = world.mic_gains
        self._c = world.speed_of_sound_m_s
        self._fs = world.sample_rate_hz
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self.latest_sample = 0  # one past the newest sample read so far: the scene's "now"

    @property
    def n_mics(self) -> int:
        return int(self._mics.shape[0])

    @property
    def now_s(self) -> float:
        """The scan time of the newest sample read (what a camera sees now)."""
        return self.latest_sample / self._fs

    def positions_at(self, t_s: float) -> np.ndarray:
        """(n_sources, 3) the sources' positions at time t_s of the scan."""
        return np.array([s.trajectory.at(t_s) for s in self.sources]).reshape(-1, 3)

    def mic_volts(self, start: int, n_samples: int) -> np.ndarray:
        """(n_samples, M) microphone voltages (noise-free) for indices start .. start + n - 1
        (read-only)."""
        if start < 0 or n_samples < 0:
            raise ValueError(f"sample range {start}+{n_samples} must be non-negative")
        first, last = start // CHUNK_SAMPLES, (start + n_samples - 1) // CHUNK_SAMPLES
        if n_samples == 0:
            return np.zeros((0, self.n_mics))
        with self._lock:
            self.latest_sample = max(self.latest_sample, start + n_samples)
        offset = start - first * CHUNK_SAMPLES
        if first == last:  # the usual read: a read-only view of one cached chunk
            return self._chunk(first)[offset: offset + n_samples]
        parts = [self._chunk(c) for c in range(first, last + 1)]
        return np.concatenate(parts)[offset: offset + n_samples]

    def _chunk(self, index: int) -> np.ndarray:
        with self._lock:
            cached = self._cache.get(index)
            if cached is not None:
                self._cache.move_to_end(index)
                return cached
        volts = np.zeros((CHUNK_SAMPLES, self.n_mics))
        for k, source in enumerate(self.sources):
            if source.frequency_hz is None:
                volts += self._noise_chunk(index, k, source)
            else:
                volts += self._tone_chunk(index, source)
        volts *= self._gain
        volts.flags.writeable = False
        with self._lock:
            self._cache[index] = volts
            while len(self._cache) > CACHED_CHUNKS:
                self._cache.popitem(last=False)
        return volts

    def _tone_chunk(self, index: int, source: LiveSource) -> np.ndarray:
        """The tone at every sample, the source where it is at that sample (its distance to
        each microphone interpolated linearly between knots `KNOT_SAMPLES` apart: the
        distance changes smoothly, so the error is far below a micrometre at walking speed)."""
        assert source.frequency_hz is not None
        n = CHUNK_SAMPLES
        start = index * n
        knots = (start + np.arange(0, n + 1, KNOT_SAMPLES)) / self._fs
        r_knots = np.maximum(np.linalg.norm(
            source.trajectory.at(knots)[:, None, :] - self._mics[None, :, :], axis=2), 1e-3)
        frac = (np.arange(KNOT_SAMPLES) / KNOT_SAMPLES).astype(np.float32)
        r0 = r_knots[:-1].astype(np.float32)
        r = (r0[:, None, :] + frac[None, :, None] * np.diff(r_knots, axis=0).astype(
            np.float32)[:, None, :]).reshape(n, self.n_mics)
        omega = 2.0 * np.pi * source.frequency_hz
        # the phase omega (t - r / c - latency) in float32, its large part omega t reduced
        # modulo 2 pi in float64 first (what is left is below 300 rad: float32 phase errors
        # below 2e-5 rad)
        wt = np.mod(omega * (start + np.arange(n)) / self._fs, 2.0 * np.pi).astype(np.float32)
        phase = r * np.float32(-omega / self._c)
        phase += wt[:, None]
        phase -= (omega * self._latency).astype(np.float32)
        np.sin(phase, out=phase)
        phase *= np.float32(np.sqrt(2.0) * source.rms_v_at_1m)
        phase /= r
        return phase.astype(np.float64)

    def _noise_chunk(self, index: int, k: int, source: LiveSource) -> np.ndarray:
        """White noise delayed by a linear phase (module docstring)."""
        n = CHUNK_SAMPLES
        start = index * n
        centre_t = (start + n / 2) / self._fs
        r = np.maximum(np.linalg.norm(self._mics - source.trajectory.at(centre_t), axis=1), 1e-3)
        delay = r / self._c + self._latency  # (M,) seconds
        lead = MARGIN_SAMPLES + int(np.ceil(delay.max() * self._fs))
        size = scipy.fft.next_fast_len(n + lead + MARGIN_SAMPLES, real=True)
        signal = self._white(k, source, start - lead, size)
        spectrum = scipy.fft.rfft(signal)
        # exp(-2 pi i f_k d) for the bins f_k = k df, as powers of exp(-2 pi i df d)
        step = np.exp(-2j * np.pi * (self._fs / signal.size) * delay)
        shift = np.empty((delay.size, spectrum.size), dtype=np.complex128)
        shift[:, 0] = 1.0
        shift[:, 1:] = step[:, None]
        np.cumprod(shift, axis=1, out=shift)
        shift *= spectrum
        delayed = scipy.fft.irfft(shift, n=size, axis=1)[:, lead: lead + n]
        return (source.rms_v_at_1m * delayed / r[:, None]).T

    def _white(self, k: int, source: LiveSource, start: int, n: int) -> np.ndarray:
        """Unit white noise of source k at indices start .. start + n - 1 (any range, negative
        indices included: the same values whenever asked)."""
        first, last = start // CHUNK_SAMPLES, (start + n - 1) // CHUNK_SAMPLES
        parts = [np.random.default_rng([self.world.seed, 11, source.seed, k, c + 2**20])
                 .standard_normal(CHUNK_SAMPLES) for c in range(first, last + 1)]
        offset = start - first * CHUNK_SAMPLES
        return np.concatenate(parts)[offset: offset + n]


def world_truth(world: World) -> dict:
    """The world's array as a calibration result would state it (microphones with their
    boards, the speed of sound now, the cameras, the board latencies): the geometry a live
    view of a simulated scene is computed with when no calibration was run."""
    layout = world.layout
    return {
        "microphones": [{"id": m, "position_m": layout.mic_positions_m[m].tolist(),
                         "board": layout.boards[ref.board].serial}
                        for m, ref in enumerate(layout.mic_inputs)],
        "speed_of_sound_m_s": world.speed_of_sound_m_s,
        "cameras": [c.to_json() for c in layout.cameras],
        "board_latencies_s": {b.serial: float(lat)
                              for b, lat in zip(layout.boards, world.board_latencies_s,
                                                strict=True)},
    }


def demo_scene(world: World) -> LiveScene:
    """The live view's simulated scene: a speaker playing a 4 kHz tone carried around a loop
    1 m in front of camera 0 (once every 8 s, back to its start), a second speaker at 1.6 kHz
    standing at the right, and a broadband noise source 2.5 m away at the top left."""
    loop = np.array([[-0.35, -0.15, 1.0], [0.3, -0.15, 1.0], [0.3, 0.2, 1.0],
                     [-0.35, 0.2, 1.0], [-0.35, -0.15, 1.0]])
    return LiveScene(world, [
        LiveSource(Trajectory(loop, np.array([0.0, 3.0, 4.0, 7.0, 7.999]), period_s=8.0),
                   0.05, 4000.0),
        LiveSource(Trajectory.still([0.45, 0.05, 1.2]), 0.05, 1600.0),
        LiveSource(Trajectory.still([-0.8, -0.6, 2.5]), 0.02, None, seed=1),
    ])
