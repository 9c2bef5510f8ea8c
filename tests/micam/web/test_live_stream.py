"""The page's live acoustic view in headless Chromium: the Live button puts the daemon in live
mode, the page shows maps drawn over camera 0 (micam web --geometry) with their latency, the
Record button stores the latest seconds, and Leave live brings the daemon back to idle."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from selenium.webdriver.common.by import By

from micam.demo_loop import Loop
from micam.web.testing import Chromium, WebProcess
from sim.arrays import array_layout
from sim.live_scene import world_truth
from sim.world import World


@pytest.fixture(scope="module")
def live_page(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Loop, WebProcess]]:
    root = tmp_path_factory.mktemp("live-web")
    truth = root / "truth.json"  # the simulated array as a calibration states it
    truth.write_text(json.dumps(world_truth(World(layout=array_layout("scatter48"), seed=3))))
    with Loop(root, poses=2, array="scatter48", mls_order=9, seed=3) as loop:
        web = WebProcess(loop.control, root / "web.log", "--geometry", str(truth),
                         "--live-fps", "5")
        try:
            yield loop, web
        finally:
            web.stop()


@pytest.mark.slow
def test_the_page_shows_live_maps_records_and_leaves(live_page, chromium: type[Chromium],
                                                      screenshots: Path) -> None:
    loop, web = live_page
    b = chromium(width=1000, height=1400)
    try:
        b.driver.get(web.url + "/")
        b.wait("window.micam.snapshots > 0 && !document.getElementById('live-start').disabled",
               what="Live enabled")
        b.driver.find_element(By.ID, "live-start").click()
        b.wait("document.body.dataset.state === 'live'", what="the daemon live")
        b.wait("!document.getElementById('live-stream').classList.contains('hidden') && "
               "Number(document.getElementById('live-stream').dataset.sample) > 0",
               timeout_s=60, what="a live map")
        first = int(b.js("return Number(document.getElementById('live-stream').dataset.sample)"))
        b.wait(f"Number(document.getElementById('live-stream').dataset.sample) > {first}",
               what="the next live map")
        assert "latency" in b.js("return document.getElementById('live-stream-note')"
                                 ".textContent")
        b.driver.find_element(By.ID, "live-stream-section").screenshot(
            str(screenshots / "live-stream.png"))
        b.driver.find_element(By.ID, "live-record").click()
        b.wait("document.getElementById('message').textContent.includes('live.record: done')",
               what="the recording accepted")
        b.driver.find_element(By.ID, "live-stop").click()
        b.wait("document.body.dataset.state === 'idle'", what="the daemon idle again")
    finally:
        b.close()
    with loop.client() as client:
        assert client.status().state == "idle"
