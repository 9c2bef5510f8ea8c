"""Test and benchmark helpers for the page: `micam web` in a subprocess, and headless Chromium.

The browser is Debian's `chromium` driven through Debian's `chromedriver` (packages chromium
and chromium-driver): selenium is pointed at both, so nothing downloads a browser. A missing
browser is an error that says which package to install, never a silent skip.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

CHROMIUM = os.environ.get("MICAM_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("MICAM_CHROMEDRIVER", "/usr/bin/chromedriver")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage")
START_WAIT_S = 30.0


def free_port() -> int:
    """A TCP port on loopback that nobody listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class WebProcess:
    """`micam web` in a subprocess on a free loopback port, talking to the daemon at
    `control`; ready once its page answers."""

    def __init__(self, control: str, log: Path, *extra: str, port: int | None = None,
                 env: dict[str, str] | None = None) -> None:
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.log = log
        with log.open("a") as out:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "micam.cli", "web", "--listen",
                 f"127.0.0.1:{self.port}", "--control", control, *extra],
                stdout=out, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})})
        self.wait_ready()

    def wait_ready(self, timeout_s: float = START_WAIT_S) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"micam web exited ({self.proc.returncode}); see {self.log}")
            try:
                with urllib.request.urlopen(self.url + "/api/state", timeout=2):
                    return
            except (urllib.error.URLError, OSError):
                time.sleep(0.1)
        raise RuntimeError(f"micam web did not answer within {timeout_s:g} s; see {self.log}")

    def kill(self) -> None:
        """SIGKILL: as a crash, nothing tidied."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(START_WAIT_S)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(START_WAIT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(START_WAIT_S)


def browser_missing() -> str | None:
    """Why headless Chromium cannot run here (None when it can)."""
    for path, package in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")):
        if not (Path(path).is_file() and os.access(path, os.X_OK)):
            return (f"{path} is missing: install Debian's {package} package (`apt-get install "
                    "chromium chromium-driver`; .ci/run does)")
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is missing: pip install -e '.[test]'"
    return None


class Chromium:
    """One headless Chromium (a fresh profile) driven by selenium through chromedriver, with
    `flags` added to CHROMIUM_FLAGS (e.g. `--host-resolver-rules=...`)."""

    def __init__(self, width: int = 1400, height: int = 1800, flags: tuple[str, ...] = ()
                 ) -> None:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        problem = browser_missing()
        if problem is not None:
            raise RuntimeError(problem)
        self.profile = tempfile.mkdtemp(prefix="micam-chromium-")
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for flag in (*CHROMIUM_FLAGS, *flags):
            options.add_argument(flag)
        options.add_argument(f"--user-data-dir={self.profile}")
        options.add_argument(f"--window-size={width},{height}")
        self.driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER),
                                       options=options)

    def js(self, script: str, *args: Any) -> Any:
        return self.driver.execute_script(script, *args)

    def wait(self, condition: str, timeout_s: float = 30.0, what: str = "") -> Any:
        """Poll the JavaScript expression `condition` until it is truthy; its value."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = self.js(f"return ({condition});")
            if value:
                return value
            time.sleep(0.05)
        raise AssertionError(f"the page did not show {what or condition} within {timeout_s:g} s")

    def close(self) -> None:
        try:
            self.driver.quit()
        finally:
            shutil.rmtree(self.profile, ignore_errors=True)
