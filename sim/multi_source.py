"""Several rig speakers playing uncorrelated noise at once (paper VI: four and six at a time).

The capture sequencer plays one speaker per recording (the calibration's MLS bursts). For
acoustic imaging the paper also recorded uncorrelated white noise on several speakers
together; `record_uncorrelated_noise` does that on the simulated bench directly: it loads an
independent Gaussian noise burst on the output of each chosen speaker (both outputs of a board
when two of its speakers play), fires the shared trigger and reads every microphone input, with
the world's propagation, gains, latencies, noise and 16-bit quantisation.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from daq import CODE_FULL_SCALE, InputChannel, board_model, volts_to_codes

from .analog_bench import AcousticBench


@dataclass(frozen=True)
class NoiseRecording:
    """A multi-speaker recording of the array microphones.

    Attributes:
        signals_v: (n_samples, M) microphone voltages, columns in microphone order.
        sample_rate_hz: the shared clock.
        speakers: the speakers that played.
        speakers_m: (len(speakers), 3) their positions in the camera-0 frame.
    """

    signals_v: np.ndarray
    sample_rate_hz: float
    speakers: tuple[int, ...]
    speakers_m: np.ndarray


def record_uncorrelated_noise(bench: AcousticBench, speakers: Sequence[int], duration_s: float,
                              seed: int = 0, drive_rms_v: float | Sequence[float] = 1.0
                              ) -> NoiseRecording:
    """Play independent white noise on `speakers` at the rig's current pose and record.

    Args:
        bench: the simulated bench (its world's rig pose places the speakers).
        speakers: distinct speaker indices.
        duration_s: length of each noise burst; the recording is as long.
        seed: seeds the noise drives (the bench's input noise follows the world's seed).
        drive_rms_v: RMS drive voltage per speaker (one value for all, or one per speaker);
            clipped at the output range.
    """
    world = bench.world
    layout = world.layout
    speakers = tuple(int(k) for k in speakers)
    if not speakers or len(set(speakers)) != len(speakers):
        raise ValueError(f"speakers must be distinct and at least one, got {speakers}")
    if any(not 0 <= k < len(layout.speaker_outputs) for k in speakers):
        raise ValueError(f"speaker indices must be in 0..{len(layout.speaker_outputs) - 1}")
    rms = np.broadcast_to(np.asarray(drive_rms_v, dtype=np.float64), (len(speakers),))
    fs = world.sample_rate_hz
    n = round(duration_s * fs)
    if n < 1:
        raise ValueError(f"duration {duration_s} s is shorter than one sample")
    rng = np.random.default_rng([seed, 17])
    drives: dict[int, dict[int, np.ndarray]] = {}  # board -> output channel -> volts
    for k, level in zip(speakers, rms, strict=True):
        out = layout.speaker_outputs[k]
        drives.setdefault(out.board, {})[out.channel] = level * rng.standard_normal(n)
    for b, channels in drives.items():
        spec = layout.boards[b]
        range_v = board_model(spec.model).output_range_v
        if range_v is None:
            raise ValueError(f"board {spec.serial} ({spec.model}) has no outputs for a speaker")
        chans = sorted(channels)
        volts = np.clip(np.column_stack([channels[c] for c in chans]), -range_v, range_v)
        bench.load_output(spec.serial, chans, volts_to_codes(volts, range_v), range_v)
    scan = bench.fire_trigger()
    signals = np.empty((n, layout.n_mics))
    for b, spec in enumerate(layout.boards):
        mics = [m for m, ref in enumerate(layout.mic_inputs) if ref.board == b]
        if not mics:
            continue
        range_v = board_model(spec.model).input_ranges_v[0]
        inputs = [InputChannel(channel=layout.mic_inputs[m].channel, range_v=range_v)
                  for m in mics]
        codes = bench.input_codes(spec.serial, inputs, scan, 0, n)
        signals[:, mics] = codes.astype(np.float64) * (range_v / CODE_FULL_SCALE)
    return NoiseRecording(signals, fs, speakers, world.speaker_positions()[list(speakers)])
