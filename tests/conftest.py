"""Shared fixtures: small simulated set-ups that run in a fraction of a second."""

from __future__ import annotations

import pytest

from sim.capture import SimulationOptions


@pytest.fixture
def small_options() -> SimulationOptions:
    """A quick capture: one camera, 48 microphones, short bursts, two poses."""
    return SimulationOptions(array="scatter48", poses=2, mls_order=9, seed=3)
