"""Blocks of scan points on threads: the maps do not depend on how the work is cut or shared."""

from __future__ import annotations

import numpy as np
import pytest

from calibration._cores import resolve_workers
from imaging import (
    CleanScOptions,
    PlaneGrid,
    SteeringModel,
    WelchOptions,
    beamform,
    clean_sc,
    clean_sc_spectra,
)
from imaging.csm import CrossSpectra
from imaging.parallel import point_blocks, run_blocks
from sim.arrays import sphere72

from .helpers import C, point_source_csm, subgrid

MICS = sphere72().mic_positions_m
SOURCES = np.array([[0.05, -0.02, 1.0], [-0.12, 0.08, 1.0]])
FREQS = np.arange(332, 340) * 96_000 / 4096


def wide_grid() -> PlaneGrid:
    # 61 x 61 = 3721 points: several blocks of 1024, the last one partial
    return PlaneGrid.xy_plane((-0.18, 0.18), (-0.18, 0.18), 1.0, 0.006)


def spectra_of(csm: np.ndarray) -> CrossSpectra:
    return CrossSpectra(FREQS, csm, 10, 96_000.0, WelchOptions(), np.arange(332, 340))


def noisy_csms(rank: int | None = None) -> np.ndarray:
    rng = np.random.default_rng(7)
    out = np.empty((FREQS.size, 72, 72), dtype=np.complex128)
    for i, f in enumerate(FREQS):
        noise = rng.standard_normal((72, rank or 200)) + 1j * rng.standard_normal((72, rank or 200))
        out[i] = point_source_csm(MICS, SOURCES, np.array([1.0, 0.5]), f)
        if rank is None:
            out[i] += 1e-3 * noise @ noise.conj().T
    return out


def test_point_blocks_cover_every_point_once() -> None:
    blocks = point_blocks(2500, 1024)
    assert blocks == [(0, 1024), (1024, 2048), (2048, 2500)]
    assert point_blocks(0, 1024) == []
    assert resolve_workers(None) >= 1
    with pytest.raises(ValueError, match="at least 1"):
        resolve_workers(0)


def test_an_exception_in_a_block_reaches_the_caller() -> None:
    def work(start: int, stop: int) -> None:
        if start >= 1024:
            raise RuntimeError(f"block {start}-{stop} failed")

    with pytest.raises(RuntimeError, match="block 1024-2048 failed"):
        run_blocks(work, 3000, workers=2)


@pytest.mark.parametrize("precision", ["single", "double"])
@pytest.mark.slow
def test_maps_do_not_depend_on_the_threads(precision: str) -> None:
    steering = SteeringModel(wide_grid().points, MICS, C)
    # a full-rank CSM (Cholesky) and a rank-2 one (not positive definite: the general form)
    for csm in (noisy_csms(), noisy_csms(rank=2)):
        one = beamform(spectra_of(csm), steering, clip_negative=False, precision=precision,
                       workers=1)
        two = beamform(spectra_of(csm), steering, clip_negative=False, precision=precision,
                       workers=2)
        np.testing.assert_array_equal(one, two)
        for i, f in enumerate(FREQS):
            h = steering.vectors(f)
            off = csm[i] - np.diag(np.diag(csm[i]))
            direct = 72 / 71 * np.einsum("gm,mn,gn->g", h.conj(), off, h).real
            tolerance = 1e-5 if precision == "single" else 1e-12
            assert np.abs(one[i] - direct).max() <= tolerance * np.abs(direct).max()


def test_a_block_of_a_steering_model_is_its_slice() -> None:
    points = wide_grid().points
    fresh = SteeringModel(points, MICS, C, "true level")
    computed = SteeringModel(points, MICS, C, "true level")
    computed.amplitude  # noqa: B018  (computes the full arrays first)
    for model in (fresh, computed):
        part = model.block(1000, 1500)
        np.testing.assert_allclose(part.path_difference, computed.path_difference[1000:1500],
                                   rtol=0, atol=1e-15)
        np.testing.assert_allclose(part.amplitude, computed.amplitude[1000:1500], rtol=1e-14)
    vectors = fresh.vectors_at(FREQS[:2], shared=True)
    h = next(vectors)
    with pytest.raises(ValueError, match="read-only"):
        h[0, 0] = 0.0


@pytest.mark.slow
def test_clean_sc_does_not_depend_on_threads_or_lockstep() -> None:
    grid = wide_grid()
    steering = SteeringModel(grid.points, MICS, C)
    spectra = spectra_of(noisy_csms())
    options = CleanScOptions()
    alone = [clean_sc(spectra.csm[i], steering.vectors(f), options, grid_shape=grid.shape)
             for i, f in enumerate(FREQS)]
    for workers, lockstep in ((1, 1), (1, 8), (2, 3)):
        together = clean_sc_spectra(spectra, steering, options, grid.shape, workers=workers,
                                    lockstep=lockstep)
        for a, b in zip(alone, together, strict=True):
            assert [c.index for c in a.components] == [c.index for c in b.components]
            np.testing.assert_allclose(b.clean_map, a.clean_map, rtol=1e-9,
                                       atol=1e-12 * a.clean_map.max())
            np.testing.assert_allclose([subgrid(c) for c in b.components],
                                       [subgrid(c) for c in a.components], atol=1e-9)
