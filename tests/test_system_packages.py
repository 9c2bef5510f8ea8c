"""Without Chromium or the JACK server their tests skip and say what to install; in CI, which
installs both, a missing one is a failure."""

from __future__ import annotations

from pathlib import Path

import pytest

import micam.web.testing
from micam.web.testing import browser_missing
from tests.system_packages import REQUIRE_AUDIO_ENV, REQUIRE_BROWSER_ENV, require

REPO = Path(__file__).resolve().parents[1]


def test_a_missing_browser_skips_with_the_install_command(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(micam.web.testing, "CHROMIUM", str(tmp_path / "no-chromium"))
    monkeypatch.delenv(REQUIRE_BROWSER_ENV, raising=False)
    with pytest.raises(pytest.skip.Exception,
                       match="apt-get install chromium chromium-driver"):
        require(browser_missing(), "the browser tests", REQUIRE_BROWSER_ENV)


def test_where_the_tests_are_required_a_missing_package_fails(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(REQUIRE_AUDIO_ENV, "1")
    with pytest.raises(pytest.fail.Exception, match=r"must run here \(\$MICAM_REQUIRE_AUDIO"):
        require("a JACK server: apt-get install jackd2", "the audio tests", REQUIRE_AUDIO_ENV)
    require(None, "the audio tests", REQUIRE_AUDIO_ENV)  # nothing missing: the test runs


def test_ci_requires_the_browser_and_audio_tests() -> None:
    ci = (REPO / ".ci/run").read_text()
    for env in (REQUIRE_BROWSER_ENV, REQUIRE_AUDIO_ENV):
        assert f"export {env}=1" in ci
