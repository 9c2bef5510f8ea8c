"""Killing `micam web` never disturbs a capture; a restarted page picks up where the daemon is."""

from __future__ import annotations

import json
import time
import urllib.request
from pathlib import Path

import pytest

from acquisition.contracts.protocol import StatusResult
from acquisition.contracts.session import SessionReader, journal_records

from micam.web.bridge import LIVE_FILE

from .conftest import Stack

POSES = 5  # live calibration starts once 4 poses are in (after pose 3), one pose before the end
LIVE_WAIT_S = 90.0


def _state(url: str) -> dict:
    with urllib.request.urlopen(url + "/api/state", timeout=5) as reply:
        return json.loads(reply.read())


def _wait_state(url: str, done, timeout_s: float = 60.0) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        state = _state(url)
        if done(state):
            return state
        time.sleep(0.1)
    raise AssertionError(f"the page's state did not get there within {timeout_s:g} s")


@pytest.mark.slow
def test_killing_the_page_never_disturbs_a_capture(stack: Stack) -> None:
    with stack.loop.client() as client:
        client.request("session.start", poses=POSES)
        opened = client.status().session
        assert opened is not None
        session, total = Path(opened.path), opened.steps_total
        killed_during = None
        for n in range(total):
            number = client.request("capture")["number"]

            def capturing(s: StatusResult, number: int = number) -> bool:
                return s.state == "capturing" or (
                    s.last_capture is not None and s.last_capture.number >= number)

            def captured(s: StatusResult, number: int = number) -> bool:
                return s.session is None or (
                    s.last_capture is not None and s.last_capture.number >= number)

            if n == total - 2:  # the last pose but one: kill the page while it is captured
                client.wait_until(capturing, 30, interval_s=0.01)
                killed_during = client.status().state
                stack.web.kill()
            client.wait_until(captured, 60, interval_s=0.02)
            if n == total - 2:
                web = stack.restart_web()  # restarted while the session is open
                state = _wait_state(web.url, lambda s: s["status"] is not None
                                    and s["status"]["session"] is not None)
                status = client.status()
                assert status.session is not None
                assert state["status"]["session"]["id"] == session.name
                assert state["status"]["session"]["steps_done"] == status.session.steps_done
                assert state["status"]["state"] == status.state
                assert [c["poses_seen"] for c in state["cameras"]] == [POSES - 1]
                assert len(state["status"]["coverage"]) == POSES - 1
            if n == total - 2:  # the live calibration of 4 poses on disk, the session open
                deadline = time.monotonic() + LIVE_WAIT_S
                while not (session / LIVE_FILE).exists():
                    assert time.monotonic() < deadline, "no live calibration"
                    time.sleep(0.2)
                web = stack.restart_web()  # the restarted page reads it from the daemon
                state = _wait_state(web.url, lambda s: s["live"] is not None
                                    and s["live"]["poses"] == POSES - 1)
                assert [p["poses"] for p in state["live_history"]] == [POSES - 1]
        final = client.wait_until(lambda s: s.session is None, 60)
    assert killed_during is not None
    assert final.state == "idle"
    reader = SessionReader(session)
    assert reader.status == "complete" and reader.verify() == []
    ends = [r.step for r in journal_records(session) if r.kind == "step_end"]
    assert len(ends) == len(set(ends)) == total  # every step recorded once, none twice
    # A closed session's live calibration leaves the page (its final one is in its report).
    state = _wait_state(stack.web.url, lambda s: s["status"]["session"] is None)
    assert state["live"] is None and state["live_history"] == [] and state["levels"] is None
    web = stack.restart_web()
    again = _wait_state(web.url, lambda s: s["status"] is not None)
    assert again["status"]["session"] is None and again["status"]["state"] == "idle"
    assert any(s["id"] == session.name and s["status"] == "complete"
               for s in again["sessions"]["sessions"])
