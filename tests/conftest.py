"""Shared fixtures: small simulated set-ups that run in a fraction of a second."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim.capture import SimulationOptions

AUDIO_TESTS = ("tests/daq/audio/", "tests/daq/test_board_conformance.py")
"""The tests that run a JACK server in real time: the audio backend's, and the board
conformance test's audio case."""


def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object:
    """`make test` runs the suite on every core (pytest-xdist's -n): each test module goes
    whole to one worker, so a module's session fixtures are made once, and the audio modules
    all go to one worker, one after the other, so that two JACK servers never compete for the
    cores in real time (an xrun fails a recording)."""
    from xdist.scheduler import LoadScopeScheduling

    class ModulesAndAudioTogether(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if nodeid.startswith(AUDIO_TESTS):
                return AUDIO_TESTS[0]
            return super()._split_scope(nodeid)

    return ModulesAndAudioTogether(config, log)


@pytest.fixture(autouse=True, scope="session")
def bug_logs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Where `micam` writes the tracebacks of its bugs during the tests (not the user's
    ~/.local/state): $MICAM_BUG_DIR for this run, inherited by the processes tests start."""
    import os

    from micam.cli import BUG_DIR_ENV

    path = tmp_path_factory.mktemp("bug-logs")
    os.environ[BUG_DIR_ENV] = str(path)
    return path


@pytest.fixture
def small_options() -> SimulationOptions:
    """A quick capture: one camera, 48 microphones, short bursts, two poses."""
    return SimulationOptions(array="scatter48", poses=2, mls_order=9, seed=3)


def simulated_session(tmp_path_factory: pytest.TempPathFactory, name: str, *options: str
                      ) -> Path:
    """A session recorded by `micam simulate --quiet` with these options, in a new temporary
    directory (for module- and session-scoped fixtures)."""
    from micam.cli import main

    path = tmp_path_factory.mktemp(name) / "s"
    assert main(["simulate", "--out", str(path), "--quiet", *options]) == 0
    return path


@pytest.fixture(scope="session")
def small_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A complete simulated session (48 microphones, 3 poses, short bursts: enough to calibrate),
    recorded once per test run. Read it; copy it before changing it."""
    return simulated_session(tmp_path_factory, "small-session", "--array", "scatter48",
                             "--poses", "3", "--mls-order", "9", "--seed", "3")


@pytest.fixture(scope="session")
def twelve_pose_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The 72-microphone sphere with its 3 cameras at 12 poses (MLS order 10), recorded once per
    test run for the camera and speaker tests. Read it; copy it before changing it."""
    return simulated_session(tmp_path_factory, "twelve-poses", "--poses", "12",
                             "--mls-order", "10")
