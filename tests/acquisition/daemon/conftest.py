"""The daemon fixture of the daemon tests: a daemon serving in a thread on the small world."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from .helpers import ThreadDaemon, small_config


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[ThreadDaemon]:
    running = ThreadDaemon(small_config(tmp_path))
    yield running
    running.stop()
