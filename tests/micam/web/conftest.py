"""The stack the page's tests run against: a daemon on a small simulated world, a calibration
worker and `micam web`, all as processes (readiness by handshake), once per module; and a
`micam web` alone, once for the package."""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from micam.demo_loop import Loop
from micam.web.testing import Chromium, WebProcess, browser_missing
from tests.system_packages import REQUIRE_BROWSER_ENV, require

POSES = 8  # the world's poses; sessions ask for fewer
LONE_TIMEOUT_S = 0.5


@dataclass
class Stack:
    loop: Loop
    web: WebProcess
    root: Path

    def restart_web(self) -> WebProcess:
        """Stop `micam web` (nothing to do if it was killed) and start it again on its port."""
        self.web.stop()
        self.web = WebProcess(self.loop.control, self.root / "web.log", port=self.web.port)
        return self.web


@pytest.fixture(scope="module")
def stack(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Stack]:
    root = tmp_path_factory.mktemp("web")
    with Loop(root, poses=POSES, array="scatter48", mls_order=9, seed=3) as loop:
        web = WebProcess(loop.control, root / "web.log")
        running = Stack(loop, web, root)
        try:
            yield running
        finally:
            running.web.stop()


@pytest.fixture(scope="package")
def lone_web(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WebProcess]:
    """`micam web` with no daemon behind it (its requests to one fail within 0.2 s) and a
    request timeout of LONE_TIMEOUT_S: for the tests of its HTTP side, shared by them."""
    root = tmp_path_factory.mktemp("lone-web")
    page = WebProcess(f"ipc://{root}/no-daemon", root / "web.log",
                      "--request-timeout", str(LONE_TIMEOUT_S), "--timeout", "0.2")
    try:
        yield page
    finally:
        page.stop()


@pytest.fixture
def chromium() -> Iterator[type[Chromium]]:
    """The Chromium class, once it is known to run here: without a browser the test skips
    with what to install (fails when $MICAM_REQUIRE_BROWSER is set, as .ci/run does)."""
    require(browser_missing(), "the browser tests", REQUIRE_BROWSER_ENV)
    yield Chromium


@pytest.fixture(scope="module")
def screenshots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Where the browser tests save their screenshots ($MICAM_SCREENSHOTS, else a temporary
    directory, printed)."""
    chosen = os.environ.get("MICAM_SCREENSHOTS")
    path = Path(chosen) if chosen else tmp_path_factory.mktemp("screenshots")
    path.mkdir(parents=True, exist_ok=True)
    print(f"screenshots in {path}")
    return path
