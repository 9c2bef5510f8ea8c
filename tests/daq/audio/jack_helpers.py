"""Helpers of the audio backend's tests: the JACK server's figures, a skip that says how to
install what is missing, bounded waits, and a capture taken again after a loaded machine's
xrun."""

from __future__ import annotations

import time

from sim.jack_server import (  # noqa: F401 - the figures the tests use
    CAPTURE_PORTS,
    PERIOD,
    PLAYBACK_PORTS,
    RATE_HZ,
    JackServer,
    missing_audio_stack,
)
from tests.system_packages import REQUIRE_AUDIO_ENV, require


def require_audio_stack() -> None:
    """Skip (with the install command) unless jackd, PortAudio and JACK-Client are there, or
    fail when $MICAM_REQUIRE_AUDIO is set: `.ci/run` installs them and sets it, so these tests
    run on a fresh machine."""
    require(missing_audio_stack(), "the audio backend's tests", REQUIRE_AUDIO_ENV)


def wait_for(condition, timeout_s: float, what: str, poll_s: float = 0.02):  # noqa: ANN001
    """Poll `condition()` until it is truthy (bounded in time), returning its value."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(poll_s)
    raise AssertionError(f"{what} within {timeout_s} s")


XRUN_RETRIES = 3


def acquire_whole(group, outputs):  # noqa: ANN001, ANN201
    """`group.acquire(outputs)`, again after an xrun (a late period of this shared, loaded
    machine, which a daemon also captures again: tests/daq/audio/test_audio_board.py checks
    the xrun's own outcome), at most XRUN_RETRIES times."""
    from daq import OverrunError

    for attempt in range(XRUN_RETRIES):
        try:
            return group.acquire(outputs)
        except OverrunError:
            if attempt == XRUN_RETRIES - 1:
                raise
    raise AssertionError("unreachable")

