"""Live mode in the daemon: entered and left by command, refused beside a calibration
session or for a ring that would not fit, the time data published and recorded (session
format and Acoular's HDF5 layout), and a board's overrun or unplugging ending it cleanly with
an event."""

from __future__ import annotations

import json
from contextlib import closing

import h5py
import numpy as np
import pytest
import zmq

from acquisition.daemon import live_control
from acquisition.daemon.client import DaemonError
from acquisition.contracts.protocol import SAMPLES_TOPIC, SamplesHeader
from acquisition.live.record import ACOULAR_FILE, RECORDING, STEP, read_live_recording
from acquisition.contracts.session import SessionReader
from sim.boards import SimulatedBoard

from .helpers import WAIT_S, ThreadDaemon, next_event


def wait_for_samples(client, n: int) -> None:
    client.wait_until(lambda s: s.live is not None and s.live.sample >= n, WAIT_S,
                      interval_s=0.02)


def test_live_mode_is_entered_recorded_and_left(daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        status = client.request("live.start", seconds=2.0, camera_fps=20.0)
        assert status["capacity_s"] == pytest.approx(2.0)
        assert client.status().state == "live"
        with closing(client.subscribe()) as events:
            wait_for_samples(client, 30_000)
            result = client.request("live.record", seconds=0.25)
            assert client.request("live.stop")["stopped"] is True  # announced all the same
            recorded = next_event(events, "live_recorded")
        assert recorded.error == "" and recorded.path == result["path"]
        assert client.status().state == "idle" and client.status().live is None
    reader = SessionReader(result["path"])
    assert reader.status == "complete"
    codes, fs = reader.read_recording(STEP, RECORDING)
    assert codes.shape == (24_000, len(reader.capture["columns"]))
    codes_again, _, first, frames, _ = read_live_recording(result["path"], "cam0")
    assert np.array_equal(codes_again, codes) and first >= 30_000 - 24_000
    assert frames and all(first <= f.sample < first + 24_000 for f in frames)
    mics = sorted((c["mic_id"], j, c["range_v"]) for j, c in enumerate(reader.capture["columns"])
                  if c["role"] == "mic")
    with h5py.File(f"{result['path']}/{ACOULAR_FILE}", "r") as f:
        data = f["time_data"]
        assert data.shape == (24_000, len(mics)) and data.dtype == np.float32
        assert data.attrs["sample_freq"] == fs
        expected = np.column_stack([codes[:, j] * (r / 32768) for _, j, r in mics])
        np.testing.assert_allclose(data[:], expected, rtol=1e-6)
        assert list(data.attrs["mic_ids"]) == [m for m, _, _ in mics]
    assert np.std(expected) > 1e-3  # the live scene's sources are in it, not only noise


def test_live_mode_refuses_and_is_refused_beside_a_session(daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        client.request("session.start")
        with pytest.raises(DaemonError, match=r"cannot live\.start") as refused:
            client.request("live.start")
        assert refused.value.code == "wrong_state"
        client.request("session.abort")
        client.wait_until(lambda s: s.state == "idle", WAIT_S, interval_s=0.02)
        client.request("live.start")
        with pytest.raises(DaemonError, match="live mode") as refused:
            client.request("session.start")
        assert refused.value.code == "wrong_state"
        with pytest.raises(DaemonError, match="cannot capture"):
            client.request("capture")
        client.request("live.stop")
        with pytest.raises(DaemonError, match=r"cannot live\.record"):
            client.request("live.record")


def test_the_time_data_is_published_in_order(daemon: ThreadDaemon) -> None:
    with daemon.client() as client:
        sub: zmq.Socket = zmq.Context.instance().socket(zmq.SUB)
        sub.setsockopt(zmq.SUBSCRIBE, SAMPLES_TOPIC.encode())
        sub.setsockopt(zmq.RCVTIMEO, 10_000)
        sub.connect(client.events_endpoint())
        try:
            client.request("live.start")
            messages = [sub.recv_multipart() for _ in range(6)]
            client.request("live.stop")
        finally:
            sub.close(linger=0)
    headers = [SamplesHeader.model_validate(json.loads(m[1])) for m in messages]
    assert all(m[0] == b"samples" and len(m) == 3 for m in messages)
    starts = [h.start for h in headers]
    assert starts == list(range(starts[0], starts[0] + 6 * headers[0].n_samples,
                                headers[0].n_samples))
    h = headers[0]
    assert len(messages[0][2]) == 2 * h.n_samples * h.n_columns


@pytest.mark.parametrize("fault", ["overrun_at_sample", "unplug_at_sample"])
def test_a_board_fault_ends_live_mode_with_an_event(daemon: ThreadDaemon, fault: str) -> None:
    group = daemon.hardware.group
    assert group is not None
    board = group.boards[1]
    assert isinstance(board, SimulatedBoard)  # the daemon runs the simulated world
    with daemon.client() as client, closing(client.subscribe()) as events:
        client.request("live.start")
        setattr(board.faults, fault, 20_000)
        error = next_event(events, "error")
        ended = next_event(events, "live_mode", running=False)
        status = client.wait_until(lambda s: s.state == "idle", WAIT_S, interval_s=0.02)
    assert error.step == "live" and board.identity.serial in error.message
    assert ("overrun" if fault.startswith("overrun") else "disappeared") in error.message
    assert ended.running is False and "20000" in ended.reason
    assert status.live is None


def test_a_ring_too_large_for_the_memory_is_refused(daemon: ThreadDaemon,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """live.start's seconds are bounded (30), but the ring's bytes grow with the rig's columns:
    a rig of hundreds of columns must not take gigabytes on a request."""
    monkeypatch.setattr(live_control, "MAX_RING_BYTES", 2**20)
    with daemon.client() as client:
        with pytest.raises(DaemonError, match=r"do not fit the 1 MiB .* at most 0\.1 s") as refused:
            client.request("live.start", seconds=1.0)
        assert refused.value.code == "bad_request" and client.status().state == "idle"
