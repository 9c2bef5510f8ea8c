"""Scenes for the imaging tests: exact point-source CSMs and the simulated bench."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from imaging import Component
from sim.arrays import array_layout
from sim.analog_bench import AcousticBench
from sim.geometry import RigidTransform
from sim.poses import FACING_CAMERA
from sim.world import World

C = 343.0


def point_source_csm(mics: np.ndarray, sources: np.ndarray, powers: ArrayLike, freq_hz: float,
                     c: float = C) -> np.ndarray:
    """Exact CSM (M, M) of uncorrelated monopoles: sum_s P_s a_s a_s^H with
    a_m = exp(-i k r_m) / r_m (so P_s is the source's power at 1 m)."""
    k = 2 * np.pi * freq_hz / c
    csm = np.zeros((len(mics), len(mics)), dtype=np.complex128)
    for src, p in zip(np.atleast_2d(sources), np.atleast_1d(powers), strict=True):
        r = np.linalg.norm(mics - src, axis=1)
        a = np.exp(-1j * k * r) / r
        csm += p * np.outer(a, a.conj())
    return csm


def subgrid(component: Component) -> tuple[float, float]:
    """`component`'s fractional grid index, which a map on a 2-D grid gives every component."""
    assert component.subgrid is not None
    return component.subgrid


def sphere_bench(seed: int = 0, distance_m: float = 0.8) -> AcousticBench:
    """The 72-microphone sphere with the rig facing camera 0 at distance_m."""
    world = World(layout=array_layout("sphere72"), seed=seed)
    world.place_rig(RigidTransform(FACING_CAMERA, np.array([-0.075, 0.12, distance_m])))
    return AcousticBench(world)
