"""Sound in the simulated world: exact delays, levels as documented, MLS, paths."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from daq import InputChannel, volts_to_codes
from kernel.stimulus import mls_length
from sim.arrays import scatter48, sphere72
from sim.analog_bench import AcousticBench
from sim.sound import creeping_path_length, mls_burst
from sim.world import NoiseModel, World

FS = 96_000.0


def _band_limited_delay(source: np.ndarray, received: np.ndarray, band_hz=(300, 20_000)) -> float:
    """Delay (samples) of `received` against `source`: the maximum of the band-limited
    cross-correlation, found by continuous optimisation around the best integer lag."""
    n = len(source) + len(received)
    freqs = np.fft.rfftfreq(n, 1 / FS)
    cross = np.fft.rfft(received, n) * np.conj(np.fft.rfft(source, n))
    cross[(freqs < band_hz[0]) | (freqs > band_hz[1])] = 0
    k = np.arange(len(freqs))
    lag0 = float(np.argmax(np.fft.irfft(cross, n)))

    def neg_corr(tau: float) -> float:
        return -float(np.real(np.sum(cross * np.exp(2j * np.pi * k * tau / n))))

    res = minimize_scalar(neg_corr, bounds=(lag0 - 1, lag0 + 1), method="bounded",
                          options={"xatol": 1e-7})
    return float(res.x)


def _record(world: World, speaker: int, mic_board: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Play an MLS on `speaker` and return (acoustic source signal, codes of `mic_board`)."""
    bench = AcousticBench(world)
    out = world.layout.speaker_outputs[speaker]
    drive = np.zeros((n, 2))
    drive[100:100 + 4095, out.channel] = mls_burst(12)
    codes = volts_to_codes(drive, 10.0)
    bench.load_output(world.layout.boards[out.board].serial, [0, 1], codes, 10.0)
    scan = bench.fire_trigger()
    spec = world.layout.boards[mic_board]
    n_inputs = 12 if spec.model.startswith("DT9836") else 6
    rec = bench.input_codes(spec.serial, [InputChannel(channel=c) for c in range(n_inputs)],
                            scan, 0, n)
    volts = codes[:, out.channel] * (10.0 / 32768)
    h = world.speaker.frequency_response(np.fft.rfftfreq(2 * n, 1 / FS), FS)
    source = np.fft.irfft(np.fft.rfft(volts, 2 * n) * h, 2 * n)[:n]
    return source, rec.astype(np.float64)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noiseless_recording_has_the_true_delay_within_a_hundredth_of_a_sample(seed: int) -> None:
    world = World(layout=sphere72(), noise=NoiseModel(scale=0.0), seed=seed)
    speaker = seed % 6
    mic_board = 1 + seed
    source, rec = _record(world, speaker, mic_board, 6000)
    spk = world.speaker_positions()[speaker]
    mics = [m for m, r in enumerate(world.layout.mic_inputs) if r.board == mic_board]
    for col, m in enumerate(mics):
        r = np.linalg.norm(world.layout.mic_positions_m[m] - spk)
        expected = (r / world.speed_of_sound_m_s + world.board_latencies_s[mic_board]) * FS
        assert _band_limited_delay(source, rec[:, col]) == pytest.approx(expected, abs=0.01)


def test_levels_match_the_documented_snr() -> None:
    """About 30 dB at an array microphone 1 m away, as docs/simulation.md states."""
    world = World(layout=scatter48(), seed=4)
    world.rig_pose = world.rig_pose.__class__(world.rig_pose.R, np.array([0.0, 0.0, 1.0])
                                              - world.rig_pose.R @ world.rig.speakers_m[0])
    _, rec = _record(world, 0, 0, 6000)
    noise = rec[:90].std()
    signal = rec[400:4100].std()
    spk = world.speaker_positions()[0]
    r = np.linalg.norm(world.layout.mic_positions_m[:12] - spk, axis=1).mean()
    snr_db_at_1m = 20 * np.log10(np.sqrt(max(signal**2 - noise**2, 1e-12)) * r / noise)
    assert snr_db_at_1m == pytest.approx(30.0, abs=2.5)


def test_noise_scale_zero_leaves_only_quantization() -> None:
    world = World(layout=scatter48(), noise=NoiseModel(scale=0.0), seed=1)
    _, rec = _record(world, 0, 0, 6000)
    assert np.all(rec[:50] == 0)


def test_mls_is_plus_minus_one_and_white() -> None:
    x = mls_burst(10)
    assert len(x) == 1023 and set(np.unique(x)) == {-1.0, 1.0}
    circular = np.fft.irfft(np.abs(np.fft.rfft(x)) ** 2, len(x))
    assert circular[0] == pytest.approx(1023) and np.allclose(circular[1:], -1)
    with pytest.raises(ValueError, match="MLS order"):
        mls_burst(30)


def test_the_mls_length_is_the_sequences() -> None:
    assert [mls_length(k) for k in (4, 9, 14)] == [15, 511, 16383]
    assert all(len(mls_burst(k)) == mls_length(k) for k in (4, 9, 14))


def test_creeping_path_is_longer_only_in_the_shadow() -> None:
    centre, a = np.zeros(3), 0.15
    source = np.array([0.0, 0.0, 1.0])
    front = np.array([[0.0, 0.0, a]])
    back = np.array([[0.0, 0.0, -a]])
    assert creeping_path_length(source, front, centre, a)[0] == pytest.approx(1.0 - a)
    expected_back = np.sqrt(1 - a**2) + a * (np.pi - np.arccos(a / 1.0))
    assert creeping_path_length(source, back, centre, a)[0] == pytest.approx(expected_back)
    assert expected_back > 1.0 + a
