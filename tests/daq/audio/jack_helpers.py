"""Helpers of the audio backend's tests: the JACK server's figures, a failure that says how to
install what is missing, bounded waits, and a capture taken again after a loaded machine's
xrun."""

from __future__ import annotations

import os
import time

import pytest

from sim.jack_server import (  # noqa: F401 - the figures the tests use
    CAPTURE_PORTS,
    PERIOD,
    PLAYBACK_PORTS,
    RATE_HZ,
    JackServer,
    missing_audio_stack,
)


SKIP_ENV = "MICAM_SKIP_AUDIO_TESTS"


def require_audio_stack() -> None:
    """Fail (with the install command) unless jackd, PortAudio and JACK-Client are there:
    `.ci/run` installs them, so these tests run on a fresh machine (a skip only when
    $MICAM_SKIP_AUDIO_TESTS says so, as for the browser tests)."""
    missing = missing_audio_stack()
    if missing is not None:
        if os.environ.get(SKIP_ENV):
            pytest.skip(f"audio backend tests disabled by ${SKIP_ENV}: {missing}")
        pytest.fail(f"{missing} (or set {SKIP_ENV}=1 to skip these tests)")


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

