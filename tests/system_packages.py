"""Tests that need some of Debian's packages (headless Chromium, the JACK server): without
them they skip and say what to install; where they must run (CI: .ci/run installs the packages
and sets the variables) a missing package fails them instead."""

from __future__ import annotations

import os

import pytest

REQUIRE_BROWSER_ENV = "MICAM_REQUIRE_BROWSER"
REQUIRE_AUDIO_ENV = "MICAM_REQUIRE_AUDIO"


def require(problem: str | None, tests: str, env: str) -> None:
    """Skip the calling test when `problem` (what is missing and the command that installs
    it) is not None, or fail it when $`env` is set; `tests` names them ("the browser tests")."""
    if problem is None:
        return
    if os.environ.get(env):
        pytest.fail(f"{tests} must run here (${env} is set): {problem}")
    pytest.skip(f"{tests} skipped: {problem} (${env}=1 makes this a failure, as in CI)")
