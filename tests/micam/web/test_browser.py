"""The operator's page in a real headless Chromium, against a daemon on the simulated world.

One browser drives a whole session from the page alone (start, the references, six poses with
the board found, stop, the report), checking what a person would look at on the way: the
board found per camera, the level meters named by microphone and board, the live calibration
updating, the hint drawn on camera 0's image. Five browsers connected at once must each see
every event. Another site's pages (DNS rebinding, cross-site forms and fetches) can neither
read nor drive it. Screenshots are saved (see the screenshots fixture).
"""

from __future__ import annotations

import http.server
import threading
import time
from pathlib import Path

import pytest
from selenium.webdriver.common.by import By

from calibration.report import FIGURES
from micam.web.testing import Chromium

from .conftest import Stack

REFERENCE_STEPS = 7  # six speakers and the reference microphone on its stand
SESSION_POSES = 6
FINAL_WAIT_S = 120.0


def _steps(b: Chromium) -> int:
    return int(b.js("return Number(document.getElementById('progress').dataset.steps)"))


def _shown_text(b: Chromium, element_id: str) -> str:
    """The text element `element_id` shows, found and read in one script: the page renders
    its panels again on every event, so an element found first may be gone by the time its
    text is read (selenium's StaleElementReferenceException)."""
    return str(b.js("return document.getElementById(arguments[0]).innerText", element_id))


def _capture_from_page(b: Chromium) -> None:
    """Click Capture and wait until the page shows one more step done."""
    before = _steps(b)
    b.wait("!document.getElementById('capture').disabled", what="Capture enabled")
    b.driver.find_element(By.ID, "capture").click()
    b.wait(f"Number(document.getElementById('progress').dataset.steps) > {before}",
           what=f"step {before + 1} done")


@pytest.mark.slow
def test_five_browsers_see_every_event(stack: Stack, chromium: type[Chromium]) -> None:
    browsers = []
    try:
        for _ in range(5):
            b = chromium(width=1000, height=800)
            browsers.append(b)
            b.driver.get(stack.web.url + "/")
        for b in browsers:
            b.wait("window.micam.snapshots > 0 && document.body.dataset.state === 'idle'",
                   what="the snapshot")
        with stack.loop.client() as client:
            first = client.status().last_event_seq + 1
            client.request("session.start", poses=2)
            for command in ("capture", "session.pause", "session.resume", "capture"):
                time.sleep(0.3)
                client.request(command)
            client.wait_until(lambda s: s.last_capture is not None and s.last_capture.number
                              >= 2, 30)
            client.request("session.abort")
            last = client.wait_until(lambda s: s.session is None, 30).last_event_seq
        expected = list(range(first, last + 1))
        for b in browsers:
            b.wait(f"window.micam.seen.includes({last})", what=f"event {last}")
        for n, b in enumerate(browsers):
            seen = b.js("return window.micam.seen")
            assert [s for s in seen if first <= s <= last] == expected, f"browser {n}"
            assert b.js("return document.body.dataset.state") == "idle"
        assert len(expected) > 20  # states, instructions, levels, previews, progress, ...
    finally:
        for b in browsers:
            b.close()


@pytest.mark.slow
def test_a_whole_session_from_the_page(stack: Stack, chromium: type[Chromium],
                                       screenshots: Path) -> None:
    b = chromium()
    try:
        b.driver.get(stack.web.url + "/")
        b.wait("document.body.dataset.state === 'idle'", what="an idle daemon")
        b.wait("document.querySelector('[data-camera=cam0] img[src]')", what="a preview")
        b.driver.save_screenshot(str(screenshots / "idle.png"))
        b.driver.find_element(By.ID, "start-poses").send_keys(str(SESSION_POSES + 2))
        b.driver.find_element(By.ID, "start").click()
        b.wait("document.body.dataset.state === 'references'", what="the first reference step")

        for _ in range(REFERENCE_STEPS):
            _capture_from_page(b)
        reference = b.js("return document.querySelector('.board.reference .meter') !== null")
        assert reference, "the reference microphone has its own meter"

        live_poses = set()
        for pose in range(1, SESSION_POSES + 1):
            _capture_from_page(b)
            b.wait(f"document.querySelector('#progress').dataset.poses == {pose}")
            b.wait("document.querySelector('[data-camera=cam0]').dataset.found === 'yes'",
                   what="the board found in cam0")
            seen = "1 pose seen" if pose == 1 else f"{pose} poses seen"
            b.wait(f"document.querySelector('[data-camera=cam0] .poses-seen').textContent"
                   f" === '{seen}'", what=f"{seen} by cam0")
            meters = b.js("return document.querySelectorAll('.board:not(.reference) .meter')"
                          ".length")
            assert meters == 48, "one meter per microphone"
            scale = b.js("return [...document.querySelector('.board:not(.reference)')"
                         ".querySelectorAll('.db-tick')].map((t) => t.textContent)")
            assert scale == ["0", "-30", "-60", "-90"], scale  # the meters' dBFS scale
            title = b.js("return document.querySelector('.board:not(.reference) .meter')"
                         ".getAttribute('title')")
            assert title.startswith("mic ") and "board" in title and "SNR" in title
            live = b.js("return document.getElementById('live-summary').dataset.poses")
            if live:
                live_poses.add(int(live))
        b.wait(f"document.getElementById('live-summary').dataset.poses == {SESSION_POSES}",
               timeout_s=90, what="the live calibration of every pose")
        live_poses.add(SESSION_POSES)
        assert len(live_poses) >= 2, f"the live calibration updated: {sorted(live_poses)}"
        history = b.js("return document.querySelectorAll('#chart-accuracy .point').length")
        assert history >= 2
        for chart in ("chart-accuracy", "chart-c"):  # ticks that tell their values apart
            ticks = b.js(f"return [...document.querySelectorAll('#{chart} .tick-label')]"
                         ".map((t) => [t.getAttribute('text-anchor'), t.textContent])")
            y = [text for anchor, text in ticks if anchor == "end"]
            x = [text for anchor, text in ticks if anchor == "middle"]
            assert len(y) >= 2 and len(set(y)) == len(y), (chart, y)
            assert len(x) >= 2 and len(set(x)) == len(x), (chart, x)
        assert b.js("return document.querySelectorAll('#view-top .mic').length") >= 40

        outline = b.wait("document.getElementById('hint-outline')"
                         " && document.getElementById('hint-outline').getAttribute('points')",
                         what="the hint's outline on cam0")
        points = [tuple(map(float, p.split(","))) for p in outline.split()]
        width, height = b.js("const p = document.querySelector('[data-camera=cam0] svg')"
                             ".viewBox.baseVal; return [p.width, p.height]")
        assert len(points) == 4
        assert all(0 <= x <= width and 0 <= y <= height for x, y in points), points
        assert "Next pose:" in _shown_text(b, "hint-text")
        _coverage_chart_is_labelled(b)
        _the_panels_fill_the_width(b, screenshots)
        b.driver.save_screenshot(str(screenshots / "session.png"))

        b.driver.find_element(By.ID, "stop").click()
        b.wait("document.body.dataset.state === 'idle'", what="the session closed")
        b.wait(NOTHING_OF_A_SESSION, what="the closed session's state gone")
        row = "document.querySelector('#sessions tbody tr')"
        b.wait(f"{row} && {row}.dataset.status === 'complete'", timeout_s=20,
               what="the session listed as complete")
        deadline = time.monotonic() + FINAL_WAIT_S
        while True:  # the final calibration arrives when the worker is done
            b.js(f"{row}.querySelector('button').click()")
            b.wait("document.getElementById('report').dataset.calibrated", what="the report")
            if b.js("return document.getElementById('report').dataset.calibrated") == "yes":
                break
            assert time.monotonic() < deadline, "no final calibration in the report"
            time.sleep(2)
        summary = _shown_text(b, "report-summary")
        assert summary.startswith("complete") and f"{SESSION_POSES}/{SESSION_POSES + 2} poses" \
            in summary
        assert "48 microphones" in _shown_text(b, "report-result")
        # the worker's report beside the result: its figures shown, every file a download
        links = b.js("return [...document.querySelectorAll('#report-files a[download]')]"
                     ".map((a) => a.getAttribute('download'))")
        assert {"result.json", "report.md", *FIGURES} <= set(links), links
        b.wait(f"[...document.querySelectorAll('.picture img')].filter((i) => i.complete"
               f" && i.naturalWidth > 0).length >= {len(FIGURES)}", what="the report's figures")
        kind = b.driver.execute_async_script(
            "const done = arguments[0]; fetch(document.querySelector("
            "'#report-files a[download=\"geometry.png\"]').href)"
            ".then((r) => done([r.status, r.headers.get('content-type')]));")
        assert kind == [200, "image/png"], kind
        b.js("document.getElementById('report').scrollIntoView()")
        b.driver.save_screenshot(str(screenshots / "report.png"))
        _shoot_whole(b, "sessions-section", screenshots / "report-section.png")
        _a_second_session_shows_nothing_of_the_first(b, stack, screenshots)
    finally:
        b.close()


def _shoot_whole(b: Chromium, element: str, path: Path) -> None:
    """A screenshot of the whole `element` (docs/operator.md's report), in a window made tall
    enough for it and then given back its size."""
    size = b.driver.get_window_size()
    b.driver.set_window_size(size["width"], 6000)
    try:
        b.driver.find_element(By.ID, element).screenshot(str(path))
    finally:
        b.driver.set_window_size(size["width"], size["height"])


PANEL_ROWS = """const main = document.querySelector('main'), box = main.getBoundingClientRect();
const style = getComputedStyle(main);
const inner = box.width - parseFloat(style.paddingLeft) - parseFloat(style.paddingRight);
const gap = parseFloat(style.columnGap) || 0, rows = new Map();
for (const s of main.querySelectorAll(':scope > section')) {
  const r = s.getBoundingClientRect();
  if (r.width === 0) continue;
  const top = Math.round(r.top + scrollY), row = rows.get(top) || [];
  row.push([s.id, r.width]); rows.set(top, row);
}
return {inner: inner, height: document.documentElement.scrollHeight,
  rows: [...rows.values()].map((row) => [row.map(([id]) => id).join(' '),
    1 - (row.reduce((sum, [, w]) => sum + w, 0) + gap * (row.length - 1)) / inner])};"""
MAX_EMPTY = 0.25  # of the content width, in any row of panels
MAX_HEIGHT_PX = 2300  # the page in the middle of a session, at 1400 px by 1800
NARROW_PX = 700  # a narrow window (a tablet upright): one column of panels


def _the_panels_fill_the_width(b: Chromium, screenshots: Path) -> None:
    """At 1400 px the panels use the width: no row of panels leaves more than a quarter of it
    empty, and the page stays short; on a narrow window they stack in one column, each as wide
    as the page (screenshots at 1000 px and narrow are saved). The layout before (an auto-fit
    grid) measured here: Control alone on its row (67 % of the width empty), Cameras alone
    (34 %), Sessions and Events (34 %), and a page 2579 px tall."""
    assert b.driver.get_window_size()["width"] == 1400
    measured = b.js(PANEL_ROWS)
    print("panel rows (ids, empty fraction):", measured)
    empty = [(ids, round(e, 2)) for ids, e in measured["rows"] if e > MAX_EMPTY]
    assert not empty, f"rows of panels leaving over {MAX_EMPTY:.0%} of the width empty: {empty}"
    assert measured["height"] < MAX_HEIGHT_PX, measured["height"]
    size = b.driver.get_window_size()
    try:
        for width in (1000, NARROW_PX):
            b.driver.set_window_size(width, size["height"])
            b.wait(f"document.documentElement.clientWidth < {width}", what=f"{width} px")
            b.driver.save_screenshot(str(screenshots / f"session-{width}px.png"))
        rows = b.js(PANEL_ROWS)["rows"]
        assert len(rows) == 7 and all(abs(e) < 0.01 for _, e in rows), rows  # one column
    finally:
        b.driver.set_window_size(size["width"], size["height"])


COVERAGE_TICKS = """return Object.fromEntries(['azimuth', 'elevation', 'distance'].map((axis) =>
  [axis, [...document.querySelectorAll('.coverage-chart .tick-label.' + axis)].map((t) => {
    const b = t.getBBox(); return [t.textContent, b.x, b.y, b.x + b.width, b.y + b.height]; })]))"""


def _coverage_chart_is_labelled(b: Chromium) -> None:
    """The hint's coverage chart: azimuth and elevation (and distance) ticks with labels,
    round, distinct, 0 among them, none on another or outside the chart."""
    ticks = b.js(COVERAGE_TICKS)
    width, height = b.js("const v = document.querySelector('.coverage-chart').viewBox.baseVal;"
                         " return [v.width, v.height]")
    boxes = []
    for axis in ("azimuth", "elevation", "distance"):
        labels = [t[0] for t in ticks[axis]]
        assert len(labels) >= 3 and len(set(labels)) == len(labels), (axis, labels)
        values = [float(v) for v in labels]
        assert values == sorted(values) and 0.0 in values, (axis, labels)
        boxes += [t[1:] for t in ticks[axis]]
    assert all(0 <= x0 and x1 <= width and 0 <= y0 and y1 <= height
               for x0, y0, x1, y1 in boxes), boxes
    crowded = [(p, q) for k, p in enumerate(boxes) for q in boxes[k + 1:]
               if p[0] < q[2] and q[0] < p[2] and p[1] < q[3] and q[1] < p[3]]
    assert not crowded, crowded


NOTHING_OF_A_SESSION = """(() => {
  const text = (id) => document.getElementById(id).textContent;
  return text('live-summary') === 'no live calibration yet'
    && !document.getElementById('live-summary').dataset.poses
    && document.getElementById('enough').offsetParent === null
    && document.querySelectorAll('#view-top .mic, #chart-accuracy .point').length === 0
    && !document.getElementById('hint-text') && !document.getElementById('hint-outline')
    && document.querySelectorAll('.camera .warning').length === 0
    && [...document.querySelectorAll('.poses-seen')].every((e) => e.textContent === '0 poses seen')
    && text('levels') === 'no recording yet' && text('levels-step') === ''
    && document.querySelectorAll('.meter').length === 0;
})()"""


def _a_second_session_shows_nothing_of_the_first(b: Chromium, stack: Stack,
                                                 screenshots: Path) -> None:
    """After a whole session: a second one (3 poses, whose refmic image makes cam0's 4th
    board view) starts from nothing, and a page opened in its middle gets its levels in the
    first state (no recording comes after the reload)."""
    b.driver.find_element(By.ID, "start-poses").clear()
    b.driver.find_element(By.ID, "start-poses").send_keys("3")
    b.driver.find_element(By.ID, "start").click()
    b.wait("document.body.dataset.state === 'references'", what="the second session")
    b.wait(NOTHING_OF_A_SESSION, what="nothing of the first session")
    _capture_from_page(b)
    b.wait("document.querySelectorAll('.board.reference .meter').length === 1",
           what="the second session's first levels")
    step = _shown_text(b, "levels-step")
    b.driver.refresh()
    b.wait("window.micam.snapshots === 1 && document.body.dataset.state === 'references'",
           what="the reloaded page's snapshot")
    assert _shown_text(b, "levels-step") == step
    assert b.js("return document.querySelectorAll('.board.reference .meter').length") == 1
    assert b.js("return document.querySelectorAll('.camera .warning').length") == 0, \
        "3 poses and the refmic image make 4 board views: nothing to warn about"
    late = b.js("return document.getElementById('live-summary').textContent")
    assert late == "no live calibration yet", late
    assert b.js("return document.getElementById('live-stream').offsetParent") is None, \
        "no live view (nor its alt text) while not live"
    b.driver.save_screenshot(str(screenshots / "second-session.png"))
    with stack.loop.client() as client:
        client.request("session.abort")
        client.wait_until(lambda s: s.session is None, 30)
    b.wait(NOTHING_OF_A_SESSION, what="the aborted session's state gone")


# -- another site's pages: DNS rebinding and cross-site requests -----------------------------

EVIL = "evil.example"
ATTACK = """
const done = arguments[arguments.length - 1];
const command = JSON.stringify({command: "session.start", args: {poses: 2}});
const seen = {};
async function attempt(name, request) {
  try {
    const reply = await request();
    seen[name] = {status: reply.status, type: reply.type, text: await reply.text()};
  } catch (error) {
    seen[name] = {failed: String(error)};
  }
}
(async () => {
  await attempt("state", () => fetch(arguments[0] + "/api/state"));
  await attempt("json", () => fetch(arguments[0] + "/api/command", {method: "POST",
    headers: {"content-type": "application/json"}, body: command}));
  await attempt("plain", () => fetch(arguments[0] + "/api/command", {method: "POST",
    mode: "no-cors", headers: {"content-type": "text/plain"}, body: command}));
  seen.ws = await new Promise((resolve) => {
    const ws = new WebSocket(arguments[0].replace("http", "ws") + "/ws");
    ws.onmessage = (m) => resolve("read: " + m.data.slice(0, 40));
    ws.onerror = () => resolve("error");
    ws.onclose = (e) => resolve("closed " + e.code);
    setTimeout(() => resolve("no answer"), 10000);
  });
  done(seen);
})();
"""
FORM = """<!doctype html><title>another site</title>
<form id="csrf" method="POST" action="http://127.0.0.1:{port}/api/command" enctype="text/plain">
<input name='{{"command": "session.start", "args": {{"poses": 2}}, "x": "' value='"}}'>
</form>"""


class AttackerSite:
    """Another site's page (a form posting a command to the page), served on loopback."""

    def __init__(self, page_port: int) -> None:
        body = FORM.format(port=page_port).encode()

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 (the standard library's name)
                self.send_response(200)
                self.send_header("content-type", "text/html")
                self.send_header("content-length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *_args: object) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_address[1]
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.mark.slow
def test_another_sites_pages_can_neither_read_nor_drive_the_page(
        stack: Stack, chromium: type[Chromium]) -> None:
    """A browser that resolves evil.example to 127.0.0.1 (as a DNS-rebinding attacker makes
    it): a page at http://evil.example:PORT/ (the page's own port: the rebinding case) reads
    nothing, starts nothing and gets no WebSocket; a page of another origin
    (http://evil.example:OTHER/) posting a form or a fetch to http://127.0.0.1:PORT/ starts
    nothing. The daemon's status says no session was started."""
    with stack.loop.client() as client:
        sessions_before = len(client.request("sessions.list")["sessions"])
    port = stack.web.port
    attacker = AttackerSite(port)
    b = chromium(width=800, height=600, flags=(f"--host-resolver-rules=MAP {EVIL} 127.0.0.1",))
    try:
        b.driver.set_script_timeout(30)
        b.driver.get(f"http://{EVIL}:{port}/")  # the rebinding page, on the page's port
        refusal = b.driver.find_element(By.TAG_NAME, "body").text
        assert f"does not answer to the host {EVIL}:{port}" in refusal, refusal
        seen = b.driver.execute_async_script(ATTACK, f"http://{EVIL}:{port}")
        for name in ("state", "json", "plain"):
            assert seen[name]["status"] == 421, (name, seen[name])
            assert "misdirected" in seen[name]["text"] and '"daemon"' not in seen[name]["text"]
        assert seen["ws"] in ("error", "closed 1006"), seen["ws"]

        b.driver.get(f"http://{EVIL}:{attacker.port}/")  # another origin, the real address
        seen = b.driver.execute_async_script(ATTACK, f"http://127.0.0.1:{port}")
        assert "failed" in seen["state"] and "failed" in seen["json"], seen  # no CORS
        assert seen["plain"]["type"] == "opaque", seen["plain"]  # sent blind, refused
        assert seen["ws"] in ("error", "closed 1006"), seen["ws"]
        b.js("document.getElementById('csrf').submit()")
        b.wait(f"location.href.startsWith('http://127.0.0.1:{port}/api/command')"
               " && document.body.innerText.length > 0", what="the form's answer")
        answer = b.driver.find_element(By.TAG_NAME, "body").text
        assert "another site" in answer and f"{EVIL}:{attacker.port}" in answer, answer
    finally:
        b.close()
        attacker.close()
    with stack.loop.client() as client:
        status = client.status()
        assert status.session is None and status.state == "idle"
        assert len(client.request("sessions.list")["sessions"]) == sessions_before
