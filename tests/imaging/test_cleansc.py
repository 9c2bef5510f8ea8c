"""CLEAN-SC finds uncorrelated sources and their relative levels."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import CalibrationInputError
from imaging import (
    CleanScOptions,
    PlaneGrid,
    SteeringModel,
    StopRule,
    band_bins,
    beamform_csm,
    clean_sc,
    clean_sc_spectra,
    cross_spectra,
)
from imaging.evaluate import rig_grid
from imaging.geometry import BoardPose
from sim.arrays import sphere72
from sim.multi_source import record_uncorrelated_noise

from .helpers import C, point_source_csm, sphere_bench, subgrid

MICS = sphere72().mic_positions_m


def test_exact_sources_are_recovered_with_their_powers() -> None:
    grid = PlaneGrid.xy_plane((-0.2, 0.2), (-0.2, 0.2), 1.0, 0.01)
    sources = np.array([[-0.1, 0.05, 1.0], [0.12, 0.1, 1.0], [0.0, -0.15, 1.0]])
    powers = np.array([1.0, 0.5, 0.25])
    csm = point_source_csm(MICS, sources, powers, 8000.0)
    steering = SteeringModel(grid.points, MICS, C, "true location")
    result = clean_sc(csm, steering.vectors(8000.0), CleanScOptions(max_iterations=60))
    expected = powers * np.sum(np.linalg.norm(MICS[None] - sources[:, None], axis=2) ** -2,
                               axis=1) / len(MICS)  # the true-location level of each source
    for src, level in zip(sources, expected, strict=True):
        node = np.argmin(np.linalg.norm(grid.points - src, axis=1))
        # Each source's side lobes leak into the others' coherent components (inherent in
        # CLEAN-SC): within 0.4 dB.
        assert result.clean_map[node] == pytest.approx(level, rel=0.1)
    assert result.clean_map.sum() == pytest.approx(expected.sum(), rel=0.02)


def test_map_update_equals_beamforming_the_degraded_csm() -> None:
    grid = PlaneGrid.xy_plane((-0.15, 0.15), (-0.15, 0.15), 0.9, 0.015)
    rng = np.random.default_rng(0)
    noise = rng.standard_normal((72, 200)) + 1j * rng.standard_normal((72, 200))
    csm = point_source_csm(MICS, np.array([[0.05, 0.0, 0.9], [-0.08, 0.1, 0.9]]),
                           np.array([1.0, 0.3]), 5000.0) + 1e-4 * noise @ noise.conj().T
    h = SteeringModel(grid.points, MICS, C).vectors(5000.0)
    options = CleanScOptions(max_iterations=25, stop_rule=StopRule.NONE)
    result = clean_sc(csm, h, options, residual=True)
    assert result.residual_map is not None
    degraded = csm.copy()
    for c in result.components:
        degraded -= options.loop_gain * c.peak * np.outer(c.coherence, c.coherence.conj())
    # Updating the map by linearity equals re-beamforming the degraded CSM (Acoular's way).
    expected = beamform_csm(h, degraded, True, precision="double")
    np.testing.assert_allclose(result.residual_map, expected,
                               atol=1e-10 * result.components[0].peak)


@pytest.mark.slow
def test_simulated_uncorrelated_speakers_positions_and_levels() -> None:
    bench = sphere_bench(seed=2)
    levels_db = np.array([0.0, -6.0, -3.0, -9.0])
    speakers = [0, 1, 2, 3]
    rec = record_uncorrelated_noise(bench, speakers, 0.5, seed=11,
                                    drive_rms_v=(10 ** (levels_db / 20)).tolist())
    world = bench.world
    pose = BoardPose(0, world.rig_pose, world.speaker_positions())
    grid = rig_grid(pose, world.rig.speakers_m, 0.006, 0.05)
    fs = rec.sample_rate_hz
    spectra = cross_spectra(rec.signals_v, fs, band_bins(10_000.0, 12, 4096, fs))
    steering = SteeringModel(grid.points, world.layout.mic_positions_m,
                             world.speed_of_sound_m_s, "true location")
    results = clean_sc_spectra(spectra, steering, CleanScOptions(), grid.shape)
    band = np.sum([r.clean_map for r in results], axis=0)
    found = []
    for spk in rec.speakers_m:  # the source power within 1.5 cells of each speaker
        near = np.linalg.norm(grid.points - spk, axis=1) <= 0.0091
        found.append(band[near].sum())
        peak = grid.points[near][np.argmax(band[near])]
        assert np.linalg.norm(peak - spk) <= 0.0043  # on the speaker's node or its neighbour
    # The levels seen by the array: drive level and the 1/r^2 of each speaker's distances.
    r = np.linalg.norm(world.layout.mic_positions_m[None] - rec.speakers_m[:, None], axis=2)
    expected_db = levels_db + 10 * np.log10(np.sum(r**-2, axis=1))
    found_db = 10 * np.log10(found)
    np.testing.assert_allclose(found_db - found_db[0], expected_db - expected_db[0], atol=1.0)
    assert band.sum() - sum(found) < 0.05 * band.sum()  # little power anywhere else


def test_stop_rules_and_options() -> None:
    grid = PlaneGrid.xy_plane((-0.1, 0.1), (-0.1, 0.1), 1.0, 0.02)
    noise = np.random.default_rng(1).standard_normal((72, 100))
    csm = point_source_csm(MICS, np.array([0.0, 0.0, 1.0]), 1.0, 4000.0) + 1e-5 * noise @ noise.T
    h = SteeringModel(grid.points, MICS, C).vectors(4000.0)
    assert clean_sc(csm, h, CleanScOptions(max_iterations=7,
                                           stop_rule=StopRule.NONE)).n_iterations == 7
    assert clean_sc(csm, h, CleanScOptions(min_peak_db=10)).n_iterations <= 3
    sijtsma = clean_sc(csm, h, CleanScOptions(stop_rule=StopRule.CSM_NORM))
    assert sijtsma.n_iterations < 2 * len(MICS)
    with pytest.raises(CalibrationInputError, match="loop gain"):
        CleanScOptions(loop_gain=0.0)
    with pytest.raises(ValueError):
        CleanScOptions(stop_rule="never")  # type: ignore[arg-type]  # no such rule, refused


def test_lazy_updates_pick_the_same_components_as_full_updates() -> None:
    grid = PlaneGrid.xy_plane((-0.2, 0.2), (-0.2, 0.2), 1.0, 0.01)
    rng = np.random.default_rng(4)
    noise = rng.standard_normal((72, 300)) + 1j * rng.standard_normal((72, 300))
    csm = point_source_csm(MICS, np.array([[-0.1, 0.05, 1.0], [0.12, 0.1, 1.0]]),
                           np.array([1.0, 0.4]), 6000.0) + 3e-4 * noise @ noise.conj().T
    h = SteeringModel(grid.points, MICS, C).vectors(6000.0)
    full = clean_sc(csm, h, CleanScOptions(), grid_shape=grid.shape,
                    block_points=grid.points.shape[0],
                    residual=True)
    lazy = clean_sc(csm, h, CleanScOptions(), grid_shape=grid.shape, block_points=3,
                    residual=True)
    assert lazy.residual_map is not None and full.residual_map is not None
    assert [c.index for c in lazy.components] == [c.index for c in full.components]
    np.testing.assert_allclose([subgrid(c) for c in lazy.components],
                               [subgrid(c) for c in full.components], atol=1e-9)
    np.testing.assert_allclose(lazy.clean_map, full.clean_map, rtol=1e-10)
    np.testing.assert_allclose(lazy.residual_map, full.residual_map,
                               atol=1e-10 * full.components[0].peak)
