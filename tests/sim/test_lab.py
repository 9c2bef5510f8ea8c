"""The realistic lab (sim.lab, sim.arrivals, sim.air_sensor): each effect against its
definition."""

from __future__ import annotations

import numpy as np
import pytest

from kernel.air import piston_directivity, speed_of_sound
from sim.air_sensor import SimulatedAirSensor
from sim.analog_bench import AcousticBench
from sim.arrays import planar64, sphere72
from sim.arrivals import SpeakerState, linear_phase, transfer_functions
from sim.errors import SimulationInputError
from sim.lab import EFFECTS, LabEffects, LabTruth, RoomModel
from sim.world import World

C = 343.0
FREQS = np.fft.rfftfreq(4096, 1 / 96_000.0)


def _truth(*effects: str, n_mics: int = 72, seed: int = 0) -> LabTruth:
    return LabTruth.draw(LabEffects.with_effects(effects), 6, n_mics,
                         np.random.default_rng([seed, 7]))


def _speaker(index: int = 0) -> SpeakerState:
    return SpeakerState(index, np.array([0.1, -0.05, 0.9]), np.array([0.0, 0.0, -1.0]), 0.013)


def test_profiles_and_names() -> None:
    assert LabEffects.ideal().names == ()
    assert LabEffects.realistic().names == EFFECTS
    assert LabEffects.with_effects(["room", "directivity"]).names == ("room", "directivity")
    with pytest.raises(SimulationInputError, match="unknown lab effect"):
        LabEffects.with_effects(["rooms"])


def test_turning_one_effect_on_leaves_the_others_draws_alone() -> None:
    alone = _truth("rig-tolerance")
    both = _truth("rig-tolerance", "mic-responses")
    np.testing.assert_array_equal(alone.diaphragm_offsets_m, both.diaphragm_offsets_m)


def test_acoustic_centre_far_field_and_diaphragm_near_field() -> None:
    """The array hears the acoustic centre A(f) = D + a(f) n, exactly at every frequency;
    the reference microphone 2 mm in front of the diaphragm hears the diaphragm."""
    lab = _truth("acoustic-centres")
    spk = _speaker(2)
    far = np.array([[0.02, 0.01, 0.0]])
    near = spk.diaphragm_m + 0.002 * spk.normal
    h = transfer_functions(lab, None, spk, np.vstack([far, near]), np.array([False, True]),
                           FREQS, C, directivity=False)
    a = lab.acoustic_offset_m(FREQS)[2]
    assert 1.5e-3 <= lab.acoustic_offsets_m[2] <= 4e-3
    assert a[100] != pytest.approx(a[1000], abs=1e-5)  # it moves with frequency
    centre = spk.diaphragm_m[None, :] + a[:, None] * spk.normal
    L = np.linalg.norm(far - centre, axis=1)
    np.testing.assert_allclose(h[0], np.exp(-2j * np.pi * FREQS * L / C) / L, rtol=1e-9)
    np.testing.assert_allclose(h[1], np.exp(-2j * np.pi * FREQS * 0.002 / C) / 0.002,
                               rtol=1e-9)


def test_rig_tolerance_and_print_scale_make_the_rig_as_built() -> None:
    world = World(sphere72(), lab=LabEffects.with_effects(["rig-tolerance", "print-scale"]),
                  seed=3)
    lab = world.lab_truth
    built = world.physical_rig
    offsets = built.speakers_m - world.rig.speakers_m
    np.testing.assert_allclose(offsets, lab.diaphragm_offsets_m)
    assert 0.05e-3 < np.std(offsets) < 1e-3  # 0.3 mm per axis
    assert built.square_m / world.rig.square_m == pytest.approx(lab.print_scale)
    assert 5e-4 <= abs(lab.print_scale - 1.0) <= 1e-3
    # the world puts the speakers where they were built
    np.testing.assert_allclose(world.speaker_positions(),
                               world.rig_pose.apply(built.speakers_m))


def test_capsule_responses_spread_their_group_delays_by_half_a_microsecond() -> None:
    lab = _truth("mic-responses", n_mics=2000)
    f = np.array([999.0, 1001.0])
    phase = np.unwrap(np.angle(lab.mic_response(f)), axis=1)
    group_delay = -(phase[:, 1] - phase[:, 0]) / (2 * np.pi * 2.0)
    assert np.std(group_delay) == pytest.approx(0.47e-6, rel=0.1)
    assert np.allclose(np.abs(lab.mic_response(np.array([10.0]))), 1.0, atol=1e-6)
    ideal = _truth()
    np.testing.assert_allclose(ideal.mic_response(FREQS), 1.0)


def test_air_drift_warms_or_cools_by_the_stated_amount() -> None:
    world = World(planar64(), lab=LabEffects.with_effects(["air-drift"]), seed=2)
    start = world.speed_of_sound_m_s
    assert world.lab_truth.temperature_offset_k(0.0) == 0.0
    world.set_session_progress(1.0)
    drift = world.lab_truth.temperature_drift_k
    assert abs(drift) == pytest.approx(0.4)
    assert world.air_temperature_c - world.temperature_c == pytest.approx(drift)
    expected = speed_of_sound(world.temperature_c + drift, world.relative_humidity)
    assert world.speed_of_sound_m_s == pytest.approx(expected)
    assert abs(world.speed_of_sound_m_s - start) == pytest.approx(0.24, abs=0.02)


def test_room_reflections_arrive_from_the_image_sources() -> None:
    """A floor image: the impulse response has its second peak at the image's distance,
    with the floor's reflection factor over that distance."""
    room = RoomModel(walls_m=(-50, 50, -50, 1.0, -50, 50), absorption=0.36, table_y_m=40.0)
    lab = _truth()
    spk = _speaker()
    mic = np.array([[0.0, 0.0, 0.0]])
    fs, n = 96_000.0, 8192
    freqs = np.fft.rfftfreq(n, 1 / fs)
    h = transfer_functions(lab, room, spk, mic, np.array([False]), freqs, C, False)[0]
    impulse = np.fft.irfft(h, n)
    direct = np.linalg.norm(mic[0] - spk.diaphragm_m)
    image = spk.diaphragm_m.copy()
    image[1] = 2.0 - image[1]
    reflected = np.linalg.norm(mic[0] - image)
    for length, amplitude in ((direct, 1.0), (reflected, 0.8)):
        k = round(length / C * fs)
        window = impulse[k - 3:k + 4]
        # the band-limited peak: its area (sum) is the path's amplitude over its length
        assert window.sum() == pytest.approx(amplitude / length, rel=0.05)


def test_directivity_rolls_off_high_frequencies_off_axis() -> None:
    assert piston_directivity(np.array([20_000.0]), np.array([0.0]), 0.013, C)[0, 0] == 1.0
    off = piston_directivity(np.array([500.0, 20_000.0]), np.array([0.5]), 0.013, C)[0]
    assert off[0] > 0.99 and off[1] < 0.8
    lab = _truth()
    spk = _speaker()
    receivers = np.array([[0.1, -0.05, 0.0], [0.6, -0.05, 0.4]])  # on axis, 45 degrees off
    h = transfer_functions(lab, None, spk, receivers, np.array([False, False]), FREQS, C,
                           directivity=True)
    distance = np.linalg.norm(receivers - spk.diaphragm_m, axis=1)
    gain = np.abs(h) * distance[:, None]
    k = np.searchsorted(FREQS, 15_000.0)
    assert gain[0, k] == pytest.approx(1.0) and gain[1, k] < 0.7


def test_linear_phase_is_a_pure_delay() -> None:
    delays = np.array([0.0, 1.234e-3, 5e-3])
    np.testing.assert_allclose(linear_phase(delays, FREQS[1], FREQS.size),
                               np.exp(-2j * np.pi * np.outer(delays, FREQS)), atol=1e-11)


def test_ambient_noise_is_low_frequency_and_at_its_level() -> None:
    world = World(planar64(), lab=LabEffects.with_effects(["ambient-noise"]), seed=1)
    bench = AcousticBench(world)
    world.place_reference_mic(None)
    n = 2**15
    burst = np.zeros(n)
    burst[100] = 1e-9  # a speaker must play for the scan to render; practically silent
    bench._pending = {0: burst}
    scan = bench._scans[bench.fire_trigger()]
    signals = np.array(list(bench._render(scan).values()))
    ambient = world.lab.ambient_noise
    assert ambient is not None
    rms = np.sqrt(np.mean(signals[:, 4096:n] ** 2, axis=1) / world.mic_gains[:, None].T ** 2)
    assert np.median(rms) == pytest.approx(ambient.rms_v, rel=0.3)
    spectrum = np.abs(np.fft.rfft(signals[0, :n])) ** 2
    freqs = np.fft.rfftfreq(n, 1 / world.sample_rate_hz)
    assert spectrum[freqs < 300].sum() > 20 * spectrum[freqs > 300].sum()


def test_air_sensor_reads_the_air_with_its_fixed_error() -> None:
    world = World(planar64(), lab=LabEffects.with_effects(["air-sensor", "air-drift"]),
                  seed=4)
    sensor = SimulatedAirSensor(world)
    error = world.lab_truth.sensor_errors
    assert abs(error[0]) < 5 * world.lab.air_sensor.temperature_std_k  # type: ignore[union-attr]
    first = sensor.read()
    assert first == sensor.read()  # the same pose reads the same (resumable)
    assert first.temperature_c == pytest.approx(world.air_temperature_c + error[0], abs=0.03)
    world.set_session_progress(1.0)
    later = sensor.read()
    assert later.temperature_c - first.temperature_c == pytest.approx(
        world.lab_truth.temperature_drift_k, abs=0.03)
    with pytest.raises(ValueError, match="no air sensor"):
        SimulatedAirSensor(World(planar64()))
