"""The simulated lab bench: the analog world every simulated or emulated board is wired to.

A bench stands for the cables and the air: the speakers hang on board outputs, the microphones
on board inputs, and all boards share one sample clock and one trigger line. A board (the plain
simulated board of `sim.boards`, or the emulated USB device of `sim.usb`) talks to the bench
through the `AnalogBench` protocol only:

1. before the trigger, every board with outputs loads the waveform it will play;
2. the master fires the trigger: a new *scan* begins, sample 0 is the first clock edge after it;
3. every board asks for its input codes by scan number and sample range, in any block sizes,
   and always gets the same samples for the same (scan, channel, index), whatever the order of
   the calls: the recording is a function of the world's seed, not of the read pattern.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from daq import CODE_FULL_SCALE, InputChannel, board_model, volts_to_codes

from .arrivals import SpeakerState, linear_phase, transfer_functions
from .live_scene import LiveScene
from .mistakes.plan import NO_MISTAKES, Mistakes
from .mistakes.signals import overdrive_gain
from .setups import Key, Setups
from .sound import creeping_path_length, fft_length, propagate
from .world import World


class AnalogBench(Protocol):
    """What a simulated or emulated board needs from the simulated world."""

    def load_output(self, serial: str, channels: Sequence[int], codes: np.ndarray,
                    range_v: float) -> None:
        """Queue int16 output codes (n_samples, len(channels)) of board `serial` for the next
        scan; they play from the trigger edge, then the outputs return to 0 V."""

    def fire_trigger(self) -> int:
        """Release the shared trigger: start a new scan and return its number (1, 2, ...)."""

    def wait_for_trigger(self, after_scan: int, timeout_s: float) -> int | None:
        """Block until a scan numbered above `after_scan` has started; None on timeout."""

    def input_codes(self, serial: str, channels: Sequence[InputChannel], scan: int,
                    start: int, n_samples: int) -> np.ndarray:
        """int16 codes (n_samples, len(channels)) that board `serial` samples on `channels`
        during `scan`, for sample indices start .. start + n_samples - 1."""

NOISE_CHUNK = 4096
"""Noise is drawn in chunks of this many samples, each from its own seeded generator, so that
any read pattern sees the same noise. The generators are keyed by the scan's set-up and its
number within it (sim.setups), so a resumed capture records what an uninterrupted one does."""

TAIL_SAMPLES = 4096
"""Samples rendered after the last output sample plus the longest path: the speaker's decay."""


@functools.lru_cache(maxsize=32)
def _noise_chunk(seed: int, key: Key, board: int, chunk: int, n_inputs: int) -> np.ndarray:
    """Unit input noise (NOISE_CHUNK, n_inputs) of one chunk of a board's scan (read-only,
    remembered: the reads of a long scan come in blocks smaller than a chunk)."""
    out = np.random.default_rng([seed, 2, *key, board, chunk]).standard_normal(
        (NOISE_CHUNK, n_inputs))
    out.flags.writeable = False
    return out


@dataclass
class _Scan:
    """Everything needed to produce the inputs of one scan."""

    number: int
    noise_key: Key  # the set-up and the scan's number within it (sim.setups)
    drives: dict[int, np.ndarray]  # speaker index -> drive volts from sample 0
    speaker: int | None  # the speaker whose output the capture drove (its file's number)
    rig_pose_speakers: np.ndarray  # (n_speakers, 3) speaker diaphragms at trigger time
    rig_normal: np.ndarray  # (3,) out of the rig's printed face at trigger time
    reference_mic_m: np.ndarray | None
    reference_near_speaker: int | None  # the reference microphone is in its near field
    speed_of_sound_m_s: float  # the air at trigger time
    signals: dict[tuple[int, int], np.ndarray] | None = None  # (board, channel) -> volts
    overdrive: dict[tuple[int, int], float] | None = None  # (board, channel) -> clean peak, volts
    scene: LiveScene | None = None  # sources playing throughout the scan (live mode)


class AcousticBench:
    """The `AnalogBench` of the simulated world: speakers, air, microphones and the clock.

    `mistakes` are the bench's (sim.mistakes): the cables as really plugged (microphones,
    speakers), the capsules' wiring, reflectors beside them and their dropouts, speakers that
    do not play or distort, input stages overdriven. The world's own layout stays the wiring
    as configured.

    Thread-safe: boards may read from several threads (the USB emulator does).
    """

    def __init__(self, world: World, setups: Setups | None = None,
                 mistakes: Mistakes = NO_MISTAKES) -> None:
        self.world = world
        self.setups = setups or Setups()
        self.mistakes = mistakes
        layout = world.layout
        self._board_index = {b.serial: i for i, b in enumerate(layout.boards)}
        self._mic_inputs = mistakes.mic_inputs or layout.mic_inputs
        self._speaker_of_output = {(r.board, r.channel): k for k, r in enumerate(
            mistakes.speaker_outputs or layout.speaker_outputs)}
        self._driven_speaker = {(r.board, r.channel): k
                                for k, r in enumerate(layout.speaker_outputs)}
        self._pending: dict[int, np.ndarray] = {}
        self._pending_speaker: int | None = None
        self._scan_number = 0
        self._scans: dict[int, _Scan] = {}
        self._capsule_cache: dict[tuple[int, bool], np.ndarray] = {}
        self._cond = threading.Condition()

    def board_index(self, serial: str) -> int:
        try:
            return self._board_index[serial]
        except KeyError:
            raise ValueError(f"board serial {serial!r} is not wired to this bench") from None

    def load_output(self, serial: str, channels: Sequence[int], codes: np.ndarray,
                    range_v: float) -> None:
        b = self.board_index(serial)
        volts = np.asarray(codes, dtype=np.float64) * (range_v / CODE_FULL_SCALE)
        setup = self.setups.current()
        with self._cond:
            for col, ch in enumerate(channels):
                speaker = self._speaker_of_output.get((b, ch))
                if speaker is None or not np.any(volts[:, col]):
                    continue
                self._pending_speaker = self._driven_speaker[(b, ch)]
                if self.mistakes.plays(speaker, setup):
                    self._pending[speaker] = volts[:, col].copy()

    def fire_trigger(self) -> int:
        with self._cond:
            self._scan_number += 1
            n = self._scan_number
            w = self.world
            w.start_scan()
            self._scans[n] = _Scan(
                n, self.setups.next_scan(), self._pending, self._pending_speaker,
                w.speaker_positions(), w.rig_normal(),
                None if w.reference_mic_m is None else w.reference_mic_m.copy(),
                w.reference_near_speaker, w.speed_of_sound_m_s, scene=w.live_scene)
            self._pending = {}
            self._pending_speaker = None
            for old in [k for k in self._scans if k < n - 2]:
                del self._scans[old]
            self._cond.notify_all()
            return n

    def wait_for_trigger(self, after_scan: int, timeout_s: float) -> int | None:
        with self._cond:
            if self._cond.wait_for(lambda: self._scan_number > after_scan, timeout=timeout_s):
                return self._scan_number
            return None

    @property
    def current_scan(self) -> int:
        with self._cond:
            return self._scan_number

    def input_codes(self, serial: str, channels: Sequence[InputChannel], scan: int,
                    start: int, n_samples: int) -> np.ndarray:
        b = self.board_index(serial)
        with self._cond:
            record = self._scans.get(scan)
            if record is None:
                raise ValueError(f"scan {scan} is unknown or too old to read")
            if record.signals is None:
                record.signals = self._render(record)
        volts = self._noise(record.noise_key, b, start, n_samples)
        self._add_scene(record, b, start, volts)
        out = np.empty((n_samples, len(channels)), dtype=np.int16)
        for col, ch in enumerate(channels):
            v = volts[:, ch.channel].copy()
            signal = record.signals.get((b, ch.channel))
            if signal is not None and start < signal.shape[0]:
                stop = min(start + n_samples, signal.shape[0])
                v[: stop - start] += signal[start:stop]
            peak = None if record.overdrive is None else record.overdrive.get((b, ch.channel))
            if peak is not None:  # an overdriven input stage (sim.mistakes)
                v *= overdrive_gain(peak, self.mistakes.clip_fraction, ch.range_v)
            out[:, col] = volts_to_codes(v, ch.range_v)
        return out

    def _add_scene(self, record: _Scan, board: int, start: int, volts: np.ndarray) -> None:
        """Add the live scene's microphone voltages to a board's input volts (in place)."""
        if record.scene is None:
            return
        mics = [(m, r.channel) for m, r in enumerate(self._mic_inputs) if r.board == board]
        if mics:
            scene = record.scene.mic_volts(start, volts.shape[0])
            if self.mistakes.mic_factors is not None:
                scene = scene * self.mistakes.mic_factors
            volts[:, [c for _, c in mics]] += scene[:, [m for m, _ in mics]]

    def _noise(self, key: Key, board: int, start: int, n: int) -> np.ndarray:
        """Input noise in volts (n, n_inputs of the board) for samples start .. start + n - 1."""
        model_inputs = board_model(self.world.layout.boards[board].model).n_inputs
        sigma = np.full(model_inputs, self.world.noise.array_noise_v)
        ref = self.world.layout.reference_input
        if ref.board == board:
            sigma[ref.channel] = self.world.noise.reference_noise_v
        first, last = start // NOISE_CHUNK, (start + n - 1) // NOISE_CHUNK
        chunks = [_noise_chunk(self.world.seed, key, board, c, model_inputs)
                  for c in range(first, last + 1)]
        offset = start - first * NOISE_CHUNK
        return np.concatenate(chunks)[offset: offset + n] * sigma

    def _render(self, scan: _Scan) -> dict[tuple[int, int], np.ndarray]:
        """Noise-free input voltages of every wired channel for one scan (the lab's ambient
        noise, a deterministic function of the scan, included)."""
        w = self.world
        layout = w.layout
        fs = w.sample_rate_hz
        c = scan.speed_of_sound_m_s
        signals: dict[tuple[int, int], np.ndarray] = {}
        if not scan.drives:
            return signals
        mic_keys = [(r.board, r.channel) for r in self._mic_inputs]
        positions = [layout.mic_positions_m]
        latencies = [w.board_latencies_s[[r.board for r in self._mic_inputs]]]
        gains = [w.mic_gains]
        keys = list(mic_keys)
        if scan.reference_mic_m is not None:
            ref = layout.reference_input
            positions.append(scan.reference_mic_m[None, :])
            latencies.append(np.array([w.board_latencies_s[ref.board]]))
            gains.append(np.array([w.reference_gain]))
            keys.append((ref.board, ref.channel))
        receivers = np.vstack(positions)
        latency = np.concatenate(latencies)
        gain = np.concatenate(gains) * w.speaker_pressure_gain
        n_drive = max(len(d) for d in scan.drives.values())
        max_range = 4.0 + float(np.max(np.linalg.norm(receivers, axis=1)))
        if w.lab.room is not None:
            max_range += 2 * float(np.max(np.abs(w.lab.room.walls_m)))
        n_out = n_drive + int(np.ceil((max_range / c + latency.max()) * fs))
        n_out += TAIL_SAMPLES
        n_fft = fft_length(n_out + TAIL_SAMPLES)
        freqs = np.fft.rfftfreq(n_fft, 1 / fs)
        response = w.speaker.frequency_response(freqs, fs)
        if w.lab.names:
            total = self._render_lab(scan, receivers, len(mic_keys), latency,
                                     np.concatenate(gains), n_fft, n_out, response)
        else:
            total = np.zeros((len(keys), n_out))
            for speaker, drive in scan.drives.items():
                source = scan.rig_pose_speakers[speaker]
                paths = self._path_lengths(source, receivers, n_mics=len(mic_keys))
                spectrum = self.mistakes.radiated(speaker, np.fft.rfft(drive, n_fft) * response,
                                                  n_fft)
                total += propagate(spectrum, n_fft, fs, paths / c + latency, gain / paths,
                                   n_out)
        if self.mistakes.acoustic:
            self._make_mistakes(scan, total, mic_keys)
        for key, row in zip(keys, total, strict=True):
            signals[key] = row
        return signals

    def _make_mistakes(self, scan: _Scan, total: np.ndarray,
                       mic_keys: list[tuple[int, int]]) -> None:
        """The capsules' and the input stages' mistakes on one scan's rendered volts (rows:
        the microphones in id order, then the reference microphone), in place."""
        if scan.speaker is None:
            return
        recording = (scan.noise_key[:2], scan.speaker)
        self.mistakes.after_render(recording, total, self.world.sample_rate_hz)
        clipped = self.mistakes.clipping.get(recording, ())
        peaks = {mic_keys[m]: float(np.max(np.abs(total[m]))) for m in clipped}
        scan.overdrive = {key: peak for key, peak in peaks.items() if peak > 0.0}

    def _render_lab(self, scan: _Scan, receivers: np.ndarray, n_mics: int, latency: np.ndarray,
                    sensitivity: np.ndarray, n_fft: int, n_out: int, response: np.ndarray
                    ) -> np.ndarray:
        """`_render`'s signals (n_receivers, n_out) in the realistic lab (sim.lab): every
        path of sim.arrivals, each receiver's sensitivity and capsule response, the ambient
        noise."""
        w = self.world
        lab = w.lab_truth
        fs = w.sample_rate_hz
        c = scan.speed_of_sound_m_s
        freqs = np.fft.rfftfreq(n_fft, 1 / fs)
        capsule = self._capsules(n_fft, receivers.shape[0] > n_mics)
        near = np.zeros(receivers.shape[0], dtype=bool)
        if scan.reference_near_speaker is not None and receivers.shape[0] > n_mics:
            near[n_mics:] = True
        # latency, sensitivity and capsule of every receiver, shared by every path
        receiver_part = (capsule * sensitivity[:, None]
                         * linear_phase(latency, freqs[1], freqs.size))
        spectra = np.zeros_like(receiver_part)
        radius = w.rig.speaker_diameter_m / 2
        for speaker, drive in scan.drives.items():
            state = SpeakerState(speaker, scan.rig_pose_speakers[speaker], scan.rig_normal,
                                 radius)
            is_near = near & (scan.reference_near_speaker == speaker)
            transfer = transfer_functions(lab, w.lab.room, state, receivers, is_near, freqs, c,
                                          w.lab.directivity)
            radiated = self.mistakes.radiated(speaker, np.fft.rfft(drive, n_fft) * response,
                                              n_fft)
            if lab.driver_delays_s.size:
                radiated = radiated * linear_phase(lab.driver_delays_s[speaker:speaker + 1],
                                                   freqs[1], freqs.size)[0]
            spectra += transfer * radiated[None, :]
        spectra *= w.speaker_pressure_gain
        if w.lab.ambient_noise is not None:
            spectra += self._ambient_spectra(scan, receivers, freqs, n_fft)
        spectra *= receiver_part
        return np.fft.irfft(spectra, n=n_fft, axis=1)[:, :n_out]

    def _capsules(self, n_fft: int, with_reference: bool) -> np.ndarray:
        """(n_mics [+ 1], n_freq) capsule responses on the rFFT grid of n_fft (remembered:
        the responses never change)."""
        key = (n_fft, with_reference)
        if key not in self._capsule_cache:
            lab = self.world.lab_truth
            freqs = np.fft.rfftfreq(n_fft, 1 / self.world.sample_rate_hz)
            rows = [lab.mic_response(freqs)]
            if with_reference:
                rows.append(lab.reference_response(freqs)[None, :])
            self._capsule_cache[key] = np.vstack(rows)
        return self._capsule_cache[key]

    def _ambient_spectra(self, scan: _Scan, receivers: np.ndarray, freqs: np.ndarray,
                         n_fft: int) -> np.ndarray:
        """rFFT (n_receivers, n_freq) of the lab's low-frequency ambient noise during `scan`,
        as the voltage of a microphone of unit sensitivity: plane waves from the lab's fixed
        directions plus an incoherent part. Seeded by the world's seed and the scan, like the
        input noise."""
        w = self.world
        amb = w.lab.ambient_noise
        assert amb is not None
        rng = np.random.default_rng([w.seed, 6, *scan.noise_key])  # what is captured (sim.setups)
        shape = 1.0 / (1.0 + (freqs / amb.corner_hz) ** 2)
        shape[0] = 0.0
        # time-domain variance of irfft(Z * shape) for unit complex Gaussian Z per bin
        unit_var = 2.0 * float(np.sum(shape**2)) / n_fft**2
        sigma = amb.rms_v / np.sqrt(unit_var)
        n_recv = receivers.shape[0]

        def gaussian(shape_: tuple[int, ...]) -> np.ndarray:
            return (rng.standard_normal(shape_) + 1j * rng.standard_normal(shape_)) / np.sqrt(2)

        directions = w.lab_truth.ambient_directions
        coherent = np.zeros((n_recv, freqs.size), dtype=np.complex128)
        if directions.shape[0]:
            share = np.sqrt((1.0 - amb.incoherent_fraction) / directions.shape[0])
            for d in directions:
                # a plane wave travelling along d reaches X at d.X / c (relative to the origin)
                delay = receivers @ d / scan.speed_of_sound_m_s
                delay -= delay.min()
                coherent += share * gaussian((freqs.size,))[None, :] * linear_phase(
                    delay, freqs[1], freqs.size)
        incoherent = np.sqrt(amb.incoherent_fraction) * gaussian((n_recv, freqs.size))
        return sigma * shape[None, :] * (coherent + incoherent)

    def _path_lengths(self, source: np.ndarray, receivers: np.ndarray, n_mics: int) -> np.ndarray:
        """Acoustic path length from a source to every receiver (array mics first)."""
        paths = np.linalg.norm(receivers - source, axis=1)
        body = self.world.layout.body
        if self.world.body_diffraction and body is not None:
            paths[:n_mics] = creeping_path_length(source, receivers[:n_mics], body.centre_m,
                                                  body.radius_m)
        return np.maximum(paths, 1e-4)
