"""What protocol version 2 added for the operator's page: describe, previews on demand,
session files, per-channel flags, poses seen per camera and camera 0's coverage."""

from __future__ import annotations

import base64
import json
import os
import time

import cv2
import numpy as np
import pytest

from acquisition.daemon.client import DaemonError, EventStream
from acquisition.contracts.protocol import (
    CAMERA_MIN_VIEWS,
    LevelsEvent,
    PreviewEvent,
    ProgressEvent,
)
from calibration.camera.camera_calibration import MIN_VIEWS

from .helpers import ThreadDaemon, capture

REFERENCE_STEPS = 7


def _events(stream: EventStream, seconds: float) -> list:
    deadline = time.monotonic() + seconds
    found = []
    while (left := deadline - time.monotonic()) > 0:
        event = stream.next(left)
        if event is not None:
            found.append(event)
    return found


def test_describe_names_every_column(daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        d = client.request("describe")
    roles = [c["role"] for c in d["columns"]]
    assert roles.count("reference") == 1 and roles.count("mic") == 48
    mics = [c for c in d["columns"] if c["role"] == "mic"]
    assert sorted(c["mic_id"] for c in mics) == list(range(48))
    capture_config = daemon.hardware.config
    assert [c["board"] for c in d["columns"]] == [c.board for c in capture_config.columns]
    assert d["cameras"] == [c.name for c in capture_config.cameras]
    assert d["quality"]["min_snr_db"] == daemon.config.quality.min_snr_db
    assert d["camera_min_views"] == CAMERA_MIN_VIEWS == MIN_VIEWS


@pytest.mark.slow
def test_previews_only_while_asked_for(daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        previews = client.subscribe(previews=True)
        plain = client.subscribe()
        try:
            time.sleep(0.3)  # the subscriptions reach the publisher
            assert not [e for e in _events(previews, 1.0) if isinstance(e, PreviewEvent)]
            assert client.request("previews", seconds=1.5)["seconds"] > 1.0
            shown = [e for e in _events(previews, 1.2) if isinstance(e, PreviewEvent)]
            assert 1 <= len(shown) <= 1.2 * daemon.config.previews.fps + 1
            image = cv2.imdecode(np.frombuffer(base64.b64decode(shown[0].jpeg_b64), np.uint8),
                                 cv2.IMREAD_COLOR)
            assert image is not None
            assert image.shape[1] == shown[0].width <= daemon.config.previews.width
            assert shown[0].step is None and shown[0].camera == "cam0"
            assert not [e for e in _events(plain, 0.2) if isinstance(e, PreviewEvent)]
            client.request("previews", seconds=0)
            time.sleep(0.2)
            _events(previews, 0.1)
            assert not [e for e in _events(previews, 1.0) if isinstance(e, PreviewEvent)]
        finally:
            previews.close()
            plain.close()


@pytest.mark.slow
def test_levels_flags_poses_seen_and_coverage(daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        client.request("session.start", poses=2)
        stream = client.subscribe(previews=True)
        try:
            client.request("previews", seconds=60)
            for _ in range(REFERENCE_STEPS + 1):
                capture(client)
            status = client.status()
            events = _events(stream, 0.5)
        finally:
            stream.close()
    levels = [e for e in events if isinstance(e, LevelsEvent)]
    reference = [e for e in levels if e.step.startswith("reference/")]
    pose = [e for e in levels if e.step.startswith("pose/")]
    columns = daemon.hardware.config.columns
    ref_column = [j for j, c in enumerate(columns) if c.role == "reference"]
    assert reference and all(e.listening == ref_column for e in reference)
    assert pose and all(len(e.listening) == 48 and e.dead_channels == [] for e in pose)
    progress = [e for e in events if isinstance(e, ProgressEvent) and e.step == "pose/0000"]
    assert progress[-1].cameras[0].poses_seen == 1 and progress[-1].outline is not None
    assert [c.poses_seen for c in status.cameras] == [1]
    # the refmic image is a board view of the camera calibration too; one pose is left
    assert [(c.board_views, c.views_left) for c in status.cameras] == [(2, 1)]
    (outline,) = status.coverage
    assert outline.step == "pose/0000" and len(outline.outline) == 4
    assert all(0 <= x <= 1 and 0 <= y <= 1 for x, y in outline.outline)
    captured = [e for e in events if isinstance(e, PreviewEvent) and e.step == "pose/0000"]
    assert captured and captured[0].found  # the capture's own image is shown


def test_session_files_stay_inside_the_calibration_directory(daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        client.request("session.start", poses=1)
        session = client.status().session
        assert session is not None
        calibration = daemon.daemon.session_root / session.id / "calibration"
        calibration.mkdir()
        (calibration / "result.json").write_text('{"a": 1}')
        os.symlink("/etc/passwd", calibration / "stolen.json")
        reply = client.request("session.file", session=session.id,
                               path="calibration/result.json")
        assert json.loads(base64.b64decode(reply["content_b64"])) == {"a": 1}
        report = client.request("session.report", session=session.id)
        assert [f["path"] for f in report["files"]] == ["calibration/result.json"]
        for path, code, why in (("manifest.json", "session_error", "only files under"),
                                ("calibration/stolen.json", "session_error", "cannot open"),
                                ("calibration/../journal.jsonl", "bad_request", "path"),
                                ("calibration/none.json", "session_error", "cannot open")):
            with pytest.raises(DaemonError, match=why) as refused:
                client.request("session.file", session=session.id, path=path)
            assert refused.value.code == code, path
        with pytest.raises(DaemonError, match="no session") as refused:
            client.request("session.file", session="nope", path="calibration/result.json")
        client.request("session.abort")
