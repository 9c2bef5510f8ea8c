"""The simulated world as an audio interface hears it: a room filter per speaker and receiver.

Between the rig's speakers (the interface's outputs) and the microphones (its inputs) the air
is linear and, while the operator holds a set-up, time-invariant: every (receiver, speaker)
pair is a fixed filter, the speaker's response delayed by the path's r / c (a fractional delay,
exact for the band-limited response, `sim.sound.propagate`) and scaled by the spreading and the
microphone's sensitivity, exactly as the simulated boards' bench renders a scan
(`sim.analog_bench`, the ideal world). `RoomFilter` holds those filters for the current set-up
and applies them block by block (overlap-save on an rFFT), which is what a JACK client can do
in its process callback; the input noise of every receiver is added, and the live scene's
sources when they play. Receivers are the array's microphones, in order, then the reference
microphone (silent while it is nowhere). Volts cross the interface at `range_v` per full scale.

What differs from the simulated boards: the interface's own output-to-input latency (the audio
server's buffers) replaces the boards' few microseconds of converter latency, and is common to
every channel (one device); noise is drawn afresh (real time never repeats); the realistic
lab's effects are not rendered (an ideal world: `sim.lab` renders whole scans, not blocks).
"""

from __future__ import annotations

import threading

import numpy as np
import scipy.fft

from .live_scene import CHUNK_SAMPLES, LiveScene
from .sound import fft_length, propagate
from .world import World

FILTER_TAPS = 4096
"""Taps of each room filter: the longest path (a few metres) plus the speaker's ringing."""
RANGE_V = 10.0
"""Volts at full scale of the interface's inputs and outputs (the capture configuration's)."""


def receivers_of(world: World) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(positions (R, 3), gains (R,), noise volts (R,)) of the microphones then the reference
    microphone (at the origin with gain 0 while it is nowhere)."""
    w = world
    ref = w.reference_mic_m
    positions = np.vstack([w.layout.mic_positions_m,
                           (np.zeros(3) if ref is None else ref)[None, :]])
    gains = np.append(w.mic_gains, 0.0 if ref is None else w.reference_gain)
    noise = np.append(np.full(w.layout.n_mics, w.noise.array_noise_v), w.noise.reference_noise_v)
    return positions, gains * w.speaker_pressure_gain, noise


def room_filters(world: World, n_taps: int = FILTER_TAPS) -> np.ndarray:
    """(R, S, n_taps) impulse responses, volts at each receiver per volt of drive at each
    speaker, for the world's current set-up."""
    fs = world.sample_rate_hz
    c = world.speed_of_sound_m_s
    positions, gains, _ = receivers_of(world)
    speakers = world.speaker_positions()
    n_fft = fft_length(2 * n_taps)
    freqs = np.fft.rfftfreq(n_fft, 1 / fs)
    response = world.speaker.frequency_response(freqs, fs)
    out = np.empty((positions.shape[0], speakers.shape[0], n_taps))
    for k, source in enumerate(speakers):
        paths = np.maximum(np.linalg.norm(positions - source, axis=1), 1e-4)
        if paths.max() / c * fs >= n_taps - 512:
            raise ValueError(f"a path of {paths.max():.1f} m is longer than the room filters "
                             f"({n_taps} taps at {fs:.0f} S/s)")
        out[:, k, :] = propagate(response, n_fft, fs, paths / c, gains / paths, n_taps)
    return out


class RoomFilter:
    """The room of one set-up applied block by block (module docstring).

    `process` is called by one thread (the audio callback); `set_up` and `play_scene` by
    another (the operator's): the filters change between blocks, never inside one.
    """

    def __init__(self, world: World, block: int, n_taps: int = FILTER_TAPS,
                 seed: int = 0) -> None:
        self.world = world
        self.block = block
        self.n_taps = n_taps
        self.n_fft = scipy.fft.next_fast_len(block + n_taps - 1, real=True)
        self.n_speakers = world.rig.n_speakers
        self.n_receivers = world.layout.n_mics + 1
        self._history = np.zeros((self.n_speakers, self.n_fft))
        self._rng = np.random.default_rng([seed, 11])
        self._lock = threading.Lock()
        self._spectra = np.zeros((self.n_receivers, self.n_speakers, self.n_fft // 2 + 1),
                                 dtype=np.complex128)
        self._noise = np.zeros(self.n_receivers)
        self._scene: LiveScene | None = None
        self._scene_start = 0
        self.frames = 0
        self.set_up()

    def set_up(self) -> None:
        """Take the world's current set-up (rig pose, reference microphone, air)."""
        spectra = np.fft.rfft(room_filters(self.world, self.n_taps), self.n_fft, axis=2)
        _, _, noise = receivers_of(self.world)
        with self._lock:
            self._spectra, self._noise = spectra, noise

    def play_scene(self, scene: LiveScene | None) -> None:
        """Let the live scene's sources play from the next block (None: stop them)."""
        with self._lock:
            self._scene, self._scene_start = scene, self.frames

    def prefetch(self, ahead_samples: int = 2 * CHUNK_SAMPLES) -> None:
        """Render the live scene's next `ahead_samples` now (on another thread than the audio
        callback's), so that the callback only reads them: a scene chunk takes milliseconds
        to render, a whole period on a busy machine."""
        with self._lock:
            scene, start = self._scene, self._scene_start
        if scene is None:
            return
        now = self.frames - start
        for first in range(now, now + ahead_samples + 1, CHUNK_SAMPLES):
            scene.mic_volts(first, 1)

    def process(self, drive_v: np.ndarray) -> np.ndarray:
        """Receiver volts (block, R) for the speakers' drive volts (block, S) of one block."""
        n = drive_v.shape[0]
        history = self._history
        history[:, :-n] = history[:, n:]
        history[:, -n:] = drive_v.T
        with self._lock:
            spectra, noise, scene, start = (self._spectra, self._noise, self._scene,
                                            self._scene_start)
        out = self._rng.standard_normal((n, self.n_receivers)) * noise
        active = np.flatnonzero(np.any(history[:, -(n + self.n_taps):] != 0.0, axis=1))
        if active.size:
            x = np.fft.rfft(history[active], axis=1)
            y = np.einsum("rsf,sf->rf", spectra[:, active], x)
            out += np.fft.irfft(y, self.n_fft, axis=1)[:, -n:].T
        if scene is not None:
            out[:, : self.world.layout.n_mics] += scene.mic_volts(self.frames - start, n)
        self.frames += n
        return out
