"""The page's live acoustic view in headless Chromium: the Live button puts the daemon in live
mode, the page shows maps drawn over camera 0 (micam web --geometry) with their latency, a
colour bar in dB and the array's spectrum; the band and range changed from the page change the
running map; the Record button stores the latest seconds, and Leave live brings the daemon back
to idle with no map left on the page."""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys
from selenium.webdriver.support.select import Select

from micam.demo_loop import Loop
from micam.web.testing import Chromium, WebProcess

MAP = "document.getElementById('live-stream')"
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
    b = chromium(width=1000, height=1800)
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
        ticks = b.js("return [...document.querySelectorAll('#live-colourbar .tick')]"
                     ".map((t) => t.textContent)")
        assert ticks == ["0", "-5", "-10", "-15"]  # --range-db 15 by default
        assert "dB" in b.js("return document.querySelector('#live-colourbar .title').textContent")
        assert b.js("return document.querySelectorAll('#live-spectrum rect.bar').length") > 10
        assert b.js("return [...document.querySelectorAll('#live-spectrum rect.bar.chosen')]"
                    ".map((r) => Number(r.dataset.centre))") == [4000]
        assert b.js(f"return {MAP}.getBoundingClientRect().width") > 800  # of a 1000 px page
        b.driver.find_element(By.ID, "live-stream-section").screenshot(
            str(screenshots / "live-stream.png"))
        area_4k = _map_area(b, "4000", "15")
        Select(b.driver.find_element(By.ID, "live-band")).select_by_visible_text("1000")
        area_1k = _map_area(b, "1000", "15")  # a wider beam: more of the view within 15 dB
        range_box = b.driver.find_element(By.ID, "live-range")
        range_box.clear()
        range_box.send_keys("40", Keys.ENTER)
        area_1k_40 = _map_area(b, "1000", "40")
        # measured: 4 %, 42 % and 74 % of the picture
        assert area_4k < 0.5 * area_1k and area_1k < 0.8 * area_1k_40, (area_4k, area_1k,
                                                                         area_1k_40)
        assert b.js("return [...document.querySelectorAll('#live-colourbar .tick')]"
                    ".map((t) => t.textContent).at(-1)") == "-40"
        b.driver.find_element(By.ID, "live-stream-section").screenshot(
            str(screenshots / "live-stream-retuned.png"))
        spectrum = b.driver.find_element(By.ID, "live-spectrum")
        b.js("arguments[0].scrollIntoView()", spectrum)
        spectrum.screenshot(str(screenshots / "live-spectrum.png"))
        b.driver.find_element(By.ID, "live-record").click()
        b.wait("document.getElementById('message').textContent.includes('live.record: done')",
               what="the recording accepted")
        b.driver.find_element(By.ID, "live-stop").click()
        b.wait("document.body.dataset.state === 'idle'", what="the daemon idle again")
        b.wait(f"{MAP}.classList.contains('hidden') && !{MAP}.hasAttribute('src') && "
               "document.getElementById('live-colourbar').classList.contains('hidden')",
               what="no map left after leaving live")
    finally:
        b.close()
    with loop.client() as client:
        assert client.status().state == "idle"


def _map_area(b: Chromium, band: str, range_db: str) -> float:
    """The share of the pixels of the first map of `band` and `range_db` shown that the map
    colours (saturated: the camera's picture is grey)."""
    b.wait(f"{MAP}.dataset.band === '{band}' && {MAP}.dataset.range === '{range_db}'",
           what=f"a map of {band} Hz, {range_db} dB")
    src = b.js(f"return {MAP}.getAttribute('src')")
    jpeg = np.frombuffer(base64.b64decode(src.partition(",")[2]), np.uint8)
    image = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)
    assert image is not None
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    return float(np.mean(hsv[:, :, 1] > 60))
