"""Each mistake of `micam simulate --mistake` against its definition, on the session's own files.

Every mistaken session is the small world of a clean one with the same seed: the boards' noise
is keyed by what is captured (sim.setups), so a recording the mistake leaves alone is the clean
one bit for bit, and one it changes differs from the clean one by the mistake and by the noise
of the channel it moved to (sigma ~ 10 codes here). Sessions: clean, and one per group of
mistakes that touch different microphones, speakers, poses or images.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.contracts.session import SessionReader
from acquisition.daemon.config import QualityConfig
from acquisition.daemon.quality import (
    checkerboard_corners,
    judge_images,
    judge_recording,
    measure,
)
from micam.simulated import record_simulated_session
from sim.capture import SimulationOptions, build_simulated_capture
from sim.errors import SimulationInputError
from sim.mistakes.images import ARM_GREY, MotionBlur
from sim.mistakes.signals import saturated

pytestmark = pytest.mark.slow  # every test here: the module records its sessions with mistakes once

FS = 96_000.0
FULL_SCALE = 32767
N_MICS = 48  # scatter48; column 48 is the reference microphone
SESSIONS = {
    "clean": (),
    "mics": ("swap-mics=12,13", "inverted-mic=20", "dead-mic=30", "close-reflector=40,15,0.4",
             "intermittent-mic=45,0.5", "mjpeg=80"),
    "speakers": ("swap-speakers=0,1", "silent-speaker=4,1", "distorted-speaker=5,3",
                 "refmic-far=2,6"),
    "shift": ("board-shift",),
    "clipped": ("clipped-bursts=0.35,4",),
    "images": ("hidden-board=0,0,0.5", "glare=1,0,40", "motion-blur=2,0,15"),
    "moved": ("moved-pose=1,10,2",),
}
POSES = range(3)


def _options(*mistakes: str) -> SimulationOptions:
    return SimulationOptions(array="scatter48", poses=3, mls_order=9, seed=3, mistakes=mistakes)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("mistakes")
    for name, mistakes in SESSIONS.items():
        record_simulated_session(root / name, _options(*mistakes))
    return {name: root / name for name in SESSIONS}


class _Files:
    """The recordings, images and truth of the sessions."""

    def __init__(self, sessions: dict[str, Path]) -> None:
        self.paths = sessions
        self.readers = {n: SessionReader(p) for n, p in sessions.items()}

    def recording(self, session: str, step: str, speaker: int) -> np.ndarray:
        codes, rate = self.readers[session].read_recording(step, f"speaker_{speaker}.wav")
        assert rate == FS
        return codes.astype(np.float64)

    def image(self, session: str, pose: int, camera: str = "cam0") -> np.ndarray:
        return self.readers[session].read_image(f"pose/{pose:04d}", f"{camera}.png")

    def truth(self, session: str) -> dict:
        return json.loads((self.paths[session] / "truth.json").read_text())

    def record(self, session: str, kind: str) -> dict:
        (record,) = [r for r in self.truth(session)["mistakes"] if r["kind"] == kind]
        return record

    def steps(self) -> list[tuple[str, int]]:
        """Every recording of the small world: (step, speaker)."""
        refs = [(f"reference/{k}", k) for k in range(6)]
        return refs + [(f"pose/{p:04d}", k) for p in POSES for k in range(6)]


@pytest.fixture(scope="module")
def files(sessions: dict[str, Path]) -> _Files:
    return _Files(sessions)


def _rms(x: np.ndarray, axis: int | None = 0) -> np.ndarray:
    return np.sqrt(np.mean(np.square(x), axis=axis))


def _noise_codes(files: _Files) -> float:
    """The boards' input noise in codes: the clean session before any sound arrives."""
    return float(np.median(_rms(files.recording("clean", "pose/0000", 0)[:200, :N_MICS])))


def _delay_s(a: np.ndarray, b: np.ndarray) -> float:
    """How much later `a` is than `b` (seconds): the phase slope of their cross-spectrum over
    the speakers' band, weighted by b's spectrum."""
    A, B = np.fft.rfft(a), np.fft.rfft(b)
    f = np.fft.rfftfreq(a.size, 1.0 / FS)
    band = (f > 1000.0) & (f < 15_000.0)
    phase = np.unwrap(np.angle(A[band] * np.conj(B[band])))
    return float(-np.polyfit(2 * np.pi * f[band], phase, 1, w=np.abs(B[band]))[0])


def _delayed(x: np.ndarray, delay_s: float) -> np.ndarray:
    n = 2 * x.size
    f = np.fft.rfftfreq(n, 1.0 / FS)
    return np.fft.irfft(np.fft.rfft(x, n) * np.exp(-2j * np.pi * f * delay_s), n)[: x.size]


# -- the microphones' cables and capsules ---------------------------------------------------

def test_swapped_mics_record_each_other(files: _Files) -> None:
    record = files.record("mics", "swap-mics")
    assert record == {"kind": "swap-mics", "microphones": [12, 13], "columns": [12, 13],
                      "boards": ["36002", "36002"], "channels": [0, 1],
                      "recorded_in_columns": [13, 12]}
    sigma = _noise_codes(files)
    for step, k in files.steps():
        mistaken, clean = files.recording("mics", step, k), files.recording("clean", step, k)
        for a, b in ((12, 13), (13, 12)):  # the channels keep their own noise: sqrt(2) sigma
            assert _rms(mistaken[:, a] - clean[:, b]) < 1.6 * sigma
        if step.startswith("pose"):
            assert _rms(mistaken[:, 12] - clean[:, 12]) > 5 * sigma


def test_an_inverted_mic_records_the_negative(files: _Files) -> None:
    record = files.record("mics", "inverted-mic")
    assert (record["microphones"], record["columns"]) == ([20], [20])
    sigma = _noise_codes(files)
    for step, k in files.steps():
        mistaken, clean = files.recording("mics", step, k), files.recording("clean", step, k)
        assert _rms(mistaken[:, 20] + clean[:, 20]) < 2.3 * sigma  # 2 sigma: the noise stays
        assert np.corrcoef(mistaken[:, 20], clean[:, 20])[0, 1] < -0.9


def test_a_dead_mic_records_idle_noise_only(files: _Files) -> None:
    assert files.record("mics", "dead-mic")["columns"] == [30]
    sigma = _noise_codes(files)
    config = QualityConfig()
    for p in POSES:
        for k in range(6):
            codes = files.recording("mics", f"pose/{p:04d}", k)
            assert abs(_rms(codes[:, 30]) / sigma - 1) < 0.15
            levels = measure(codes.astype(np.int16), 512, 511, config.clip_fraction)
            assert levels.snr_db is not None and levels.snr_db[30] < 1.0
            assert np.median(levels.snr_db[:N_MICS]) > 10.0


def test_a_close_reflector_adds_a_second_path_at_its_delay_and_gain(files: _Files) -> None:
    record = files.record("mics", "close-reflector")
    assert record["microphones"] == [40] and record["gain"] == 0.4
    assert record["delay_s"] == pytest.approx(15e-6) and record["delay_samples"] == 1.44
    for k in range(6):
        y = files.recording("mics", "pose/0001", k)[:, 40]
        x = files.recording("clean", "pose/0001", k)[:, 40]
        f = np.fft.rfftfreq(x.size, 1.0 / FS)
        band = (f > 1000.0) & (f < 15_000.0)
        X = np.fft.rfft(x)[band]
        echo = np.fft.rfft(y)[band] / X - 1.0  # the impulse response minus its direct path
        w = np.abs(X) ** 2
        gain = float(np.sum(w * np.abs(echo)) / np.sum(w))
        delay = -np.polyfit(2 * np.pi * f[band], np.unwrap(np.angle(echo)), 1, w=np.abs(X))[0]
        assert gain == pytest.approx(0.4, abs=0.01)
        assert delay == pytest.approx(15e-6, abs=0.2e-6)


def test_an_intermittent_mic_drops_to_idle_noise_in_its_stated_stretches(files: _Files) -> None:
    record = files.record("mics", "intermittent-mic")
    assert record["microphones"] == [45] and record["fraction"] == 0.5
    assert len(record["recordings"]) == 9  # half of 3 poses x 6 speakers
    sigma = _noise_codes(files)
    dropped = set()
    for r in record["recordings"]:
        mistaken = files.recording("mics", r["step"], r["speaker"])[:, 45]
        clean = files.recording("clean", r["step"], r["speaker"])[:, 45]
        kept = np.ones(clean.size, dtype=bool)
        for start, stop in r["samples"]:
            assert 512 <= start < stop <= clean.size
            assert _rms(mistaken[start:stop], None) < 1.5 * sigma  # idle noise
            assert _rms(clean[start:stop], None) > 5 * sigma  # while it hears the burst
            kept[start:stop] = False
        np.testing.assert_array_equal(mistaken[kept], clean[kept])
        dropped.add((r["step"], r["speaker"]))
    for step, k in files.steps():
        if (step, k) not in dropped:
            np.testing.assert_array_equal(files.recording("mics", step, k)[:, 45],
                                          files.recording("clean", step, k)[:, 45])


def test_mjpeg_frames_carry_jpeg_error_and_still_decode(files: _Files) -> None:
    assert files.record("mics", "mjpeg") == {"kind": "mjpeg", "cameras": [0],
                                             "camera_names": ["cam0"], "quality": 80}
    for p in POSES:
        mistaken, clean = files.image("mics", p), files.image("clean", p)
        error = mistaken.astype(np.float64) - clean
        psnr = 10 * np.log10(255.0**2 / np.mean(error**2))
        assert 35.0 < psnr < 50.0  # JPEG at 80 on a sharp pattern; never bit-exact
        _, data = cv2.imencode(".jpg", clean, [cv2.IMWRITE_JPEG_QUALITY, 80])
        np.testing.assert_array_equal(mistaken, cv2.imdecode(data, cv2.IMREAD_UNCHANGED))
        assert checkerboard_corners(mistaken, (6, 9)) is not None


def test_a_board_shift_records_every_board_on_the_next(files: _Files) -> None:
    record = files.record("shift", "board-shift")
    assert record["shift_columns"] == 12 and record["boards_shifted"] == 1
    assert record["recorded_in_columns"] == [(m + 12) % N_MICS for m in range(N_MICS)]
    latency = files.truth("clean")["board_latencies_s"]
    board_of = [m["board"] for m in files.truth("clean")["microphones"]]
    sigma = _noise_codes(files)
    mistaken = files.recording("shift", "pose/0002", 3)
    clean = files.recording("clean", "pose/0002", 3)
    for m in range(N_MICS):
        j = record["recorded_in_columns"][m]
        moved = _delayed(clean[:, m], latency[board_of[j]] - latency[board_of[m]])
        assert _rms(mistaken[:, j] - moved) < 1.8 * sigma  # its new board's latency and noise


# -- the speakers -----------------------------------------------------------------------------

def test_swapped_speakers_play_each_others_bursts(files: _Files) -> None:
    assert files.record("speakers", "swap-speakers") == {
        "kind": "swap-speakers", "speakers": [0, 1], "boards": ["36001", "36001"],
        "channels": [0, 1], "played_by": [1, 0]}
    sigma = _noise_codes(files)
    for p in POSES:
        step = f"pose/{p:04d}"
        for a, b in ((0, 1), (1, 0)):
            mistaken = files.recording("speakers", step, a)[:, :N_MICS]
            assert np.median(_rms(mistaken - files.recording("clean", step, b)[:, :N_MICS])) \
                < 1.6 * sigma
            assert np.median(_rms(mistaken - files.recording("clean", step, a)[:, :N_MICS])) \
                > 5 * sigma


def test_a_silent_speaker_leaves_its_recordings_at_idle_noise(files: _Files) -> None:
    record = files.record("speakers", "silent-speaker")
    assert (record["speakers"], record["poses"], record["whole_session"],
            record["steps"]) == ([4], [1], False, ["pose/0001"])
    sigma = _noise_codes(files)
    silent = files.recording("speakers", "pose/0001", 4)[:, :N_MICS]
    assert np.all(np.abs(_rms(silent) / sigma - 1) < 0.2)
    for p in (0, 2):
        np.testing.assert_array_equal(files.recording("speakers", f"pose/{p:04d}", 4),
                                      files.recording("clean", f"pose/{p:04d}", 4))


def test_a_distorted_speaker_saturates_like_tanh(files: _Files) -> None:
    record = files.record("speakers", "distorted-speaker")
    assert (record["speakers"], record["drive"]) == ([5], 3.0)
    sigma = _noise_codes(files)
    for p in POSES:
        mistaken = files.recording("speakers", f"pose/{p:04d}", 5)[:, :N_MICS]
        clean = files.recording("clean", f"pose/{p:04d}", 5)[:, :N_MICS]
        # every microphone hears the speaker's output through a delay and a gain, so its
        # clean recording through L tanh(x / L), L = its peak / drive, is the mistaken one
        level = np.max(np.abs(clean), axis=0) / 3.0
        assert np.median(_rms(mistaken - level * np.tanh(clean / level))) < 1.5 * sigma
        linear = clean * np.sum(mistaken * clean, axis=0) / np.sum(clean**2, axis=0)
        assert np.median(_rms(mistaken - linear)) > 1.8 * sigma  # no linear filter explains it


def test_saturation_makes_odd_harmonics_and_keeps_small_signals() -> None:
    n = 4096
    t = np.arange(n)
    tone = np.sin(2 * np.pi * 64 * t / n)  # bin 64
    out = np.abs(np.fft.rfft(np.fft.irfft(saturated(np.fft.rfft(tone), n, 3.0), n)))
    assert out[192] > 0.05 * out[64] and out[320] > 0.01 * out[64]  # 3rd and 5th
    assert out[128] < 1e-9 * out[64]  # no even ones: tanh is odd
    small = saturated(np.fft.rfft(tone), n, 1e-4)
    np.testing.assert_allclose(np.fft.irfft(small, n), tone, atol=1e-8)


def test_the_reference_mic_far_from_its_speaker(files: _Files) -> None:
    record = files.record("speakers", "refmic-far")
    assert (record["speakers"], record["steps"]) == ([2], ["reference/2"])
    assert (record["distance_m"], record["stated_distance_m"]) == (0.006, 0.002)
    mistaken = files.recording("speakers", "reference/2", 2)[:, N_MICS]
    clean = files.recording("clean", "reference/2", 2)[:, N_MICS]
    assert _rms(mistaken, None) / _rms(clean, None) == pytest.approx(2 / 6, rel=0.01)  # 1 / r
    c = files.truth("clean")["speed_of_sound_m_s"]
    assert _delay_s(mistaken, clean) == pytest.approx(0.004 / c, abs=0.1e-6)


def test_clipped_bursts_reach_full_scale_on_the_nearest_mics(files: _Files) -> None:
    record = files.record("clipped", "clipped-bursts")
    assert (record["fraction"], record["count"], record["poses"]) == (0.35, 4, [0, 1, 2])
    assert len(record["recordings"]) == 18
    truth = files.truth("clean")
    mics = np.array([m["position_m"] for m in truth["microphones"]])
    for r in record["recordings"]:
        speaker = truth["poses"][r["pose"]]["diaphragms_m"][r["speaker"]]
        nearest = np.argsort(np.linalg.norm(mics - speaker, axis=1))[:4]
        assert r["microphones"] == sorted(nearest.tolist()) == r["columns"]
        mistaken = files.recording("clipped", r["step"], r["speaker"])
        clean = files.recording("clean", r["step"], r["speaker"])
        for j in r["columns"]:
            # at full scale exactly where the clean burst is above 35 % of its peak
            at_full = np.abs(mistaken[:, j]) >= FULL_SCALE
            above = np.abs(clean[:, j]) >= 0.35 * np.max(np.abs(clean[:, j]))
            assert np.mean(at_full != above) < 0.005
        others = [j for j in range(N_MICS + 1) if j not in r["columns"]]
        np.testing.assert_array_equal(mistaken[:, others], clean[:, others])


# -- the rig and the images -------------------------------------------------------------------

def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1, 1))))


def test_a_moved_pose_is_imaged_at_one_pose_and_heard_at_another(files: _Files) -> None:
    record = files.record("moved", "moved-pose")
    assert (record["poses"], record["translation_mm"], record["rotation_deg"]) == ([1], 10, 2)
    truth = files.truth("moved")
    # the image: the board where the pose was sampled (solvePnP with the true camera)
    image = files.image("moved", 1)
    np.testing.assert_array_equal(image, files.image("clean", 1))
    found, corners = cv2.findChessboardCorners(image, (6, 9))
    assert found
    corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4))
    square = truth["rig"]["square_m"] * truth["lab"]["print_scale"]
    ix, iy = np.meshgrid(np.arange(6), np.arange(9))
    board = np.stack([ix.ravel(), iy.ravel(), np.zeros(54)], axis=1) * [square, square, 1.0]
    camera = truth["cameras"][0]
    _, rotvec, t = cv2.solvePnP(board, corners, np.array(camera["K"]), np.array(camera["dist"]))
    seen_R = cv2.Rodrigues(rotvec)[0]
    seen_centre = seen_R @ board.mean(axis=0) + t.ravel()

    def centre_and_R(pose: dict) -> tuple[np.ndarray, np.ndarray]:
        R = cv2.Rodrigues(np.array(pose["rotvec"]))[0]
        return R @ board.mean(axis=0) + np.array(pose["t_m"]), R

    def off(pose: dict) -> tuple[float, float]:
        """mm and degrees between the image's board and `pose` (OpenCV may number the
        corners from another end, which turns the frame it solves for half a turn about one
        of the pattern's axes through its centre)."""
        centre, R = centre_and_R(pose)
        turns = [np.diag(d) for d in ((1, 1, 1), (-1, -1, 1), (1, -1, -1), (-1, 1, -1))]
        return (1e3 * float(np.linalg.norm(seen_centre - centre)),
                min(_angle_deg(seen_R, R @ turn) for turn in turns))

    assert record["rig_to_cam0_images"] == truth["poses"][1]["rig_to_cam0"]
    mm, deg = off(record["rig_to_cam0_images"])
    assert mm < 0.5 and deg < 0.1
    mm, deg = off(record["rig_to_cam0_bursts"])
    assert mm == pytest.approx(10.0, abs=0.5) and deg == pytest.approx(2.0, abs=0.1)
    # the bursts: every time of flight changed as the speakers' move predicts
    mics = np.array([m["position_m"] for m in truth["microphones"]])
    c = truth["speed_of_sound_m_s"]
    for k in range(6):
        before = np.linalg.norm(mics - truth["poses"][1]["diaphragms_m"][k], axis=1)
        after = np.linalg.norm(mics - record["diaphragms_m_bursts"][k], axis=1)
        mistaken = files.recording("moved", "pose/0001", k)
        clean = files.recording("clean", "pose/0001", k)
        for m in range(0, N_MICS, 5):
            assert _delay_s(mistaken[:, m], clean[:, m]) == pytest.approx(
                (after[m] - before[m]) / c, abs=0.5e-6)


def _corner_pixels(truth: dict, pose: int) -> np.ndarray:
    """The true pixels of the pattern's inner corners in camera 0 at `pose`."""
    square = truth["rig"]["square_m"] * truth["lab"]["print_scale"]
    ix, iy = np.meshgrid(np.arange(6), np.arange(9))
    board = np.stack([ix.ravel(), iy.ravel(), np.zeros(54)], axis=1) * [square, square, 1.0]
    p = truth["poses"][pose]["rig_to_cam0"]
    camera = truth["cameras"][0]
    px, _ = cv2.projectPoints(board, np.array(p["rotvec"]), np.array(p["t_m"]),
                              np.array(camera["K"]), np.array(camera["dist"]))
    return px.reshape(-1, 2)


def test_a_hidden_board_is_dark_where_the_arm_is(files: _Files) -> None:
    record = files.record("images", "hidden-board")
    assert (record["poses"], record["cameras"], record["fraction"]) == ([0], [0], 0.5)
    assert record["hidden_fraction"] >= 0.5 and len(record["hidden_corners"]) >= 27
    image, clean = files.image("images", 0), files.image("clean", 0)
    assert checkerboard_corners(clean, (6, 9)) is not None
    assert checkerboard_corners(image, (6, 9)) is None  # what the capture's quick look sees
    px = np.round(_corner_pixels(files.truth("images"), 0)).astype(int)
    grey = image[px[:, 1], px[:, 0]].astype(float)
    hidden = np.zeros(54, dtype=bool)
    hidden[record["hidden_corners"]] = True
    assert np.all(np.abs(grey[hidden] - ARM_GREY) < 15)
    visible = image[px[~hidden, 1], px[~hidden, 0]].astype(float)
    np.testing.assert_allclose(visible, clean[px[~hidden, 1], px[~hidden, 0]], atol=40)


def test_glare_saturates_its_disc(files: _Files) -> None:
    record = files.record("images", "glare")
    assert (record["poses"], record["cameras"], record["radius_px"]) == ([1], [0], 40)
    image, clean = files.image("images", 1), files.image("clean", 1)
    v, u = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    r = np.hypot(u - record["centre_px"][0], v - record["centre_px"][1])
    assert np.all(image[r < 0.9 * 40] >= 254) and np.mean(clean[r < 0.9 * 40] >= 254) < 0.01
    np.testing.assert_array_equal(image[r > 4 * 40], clean[r > 4 * 40])
    px = _corner_pixels(files.truth("images"), 1)
    inside = np.flatnonzero(np.hypot(*(px - record["centre_px"]).T) < 40)
    assert record["corners_in_glare"] == inside.tolist() and inside.size > 0


def test_motion_blur_is_the_stated_linear_blur(files: _Files) -> None:
    record = files.record("images", "motion-blur")
    assert (record["poses"], record["cameras"], record["length_px"]) == ([2], [0], 15)
    image = files.image("images", 2).astype(np.float32)
    clean = files.image("clean", 2).astype(np.float32)
    kernel = MotionBlur(15, record["angle_deg"]).kernel().astype(np.float32)
    # both blurs are convolutions, so blurring the clean image (noise included) gives the
    # mistaken one up to the sensor noise (2 grey levels)
    blurred = cv2.filter2D(clean, -1, kernel, borderType=cv2.BORDER_REFLECT)
    assert _rms(image - blurred, None) < 2.5
    assert _rms(image - clean, None) > 6.0


# -- the world's input checks -----------------------------------------------------------------

@pytest.mark.parametrize(("mistakes", "message"), [
    (("swap-mic",), "unknown mistake 'swap-mic'"),
    (("swap-mics=1,2,3",), "takes at most 2"),
    (("swap-mics=a",), "MIC must be an integer"),
    (("swap-mics=4,4",), "swaps microphone 4 with itself"),
    (("dead-mic=48",), "there is no microphone 48 (microphones 0-47)"),
    (("glare=0,1",), "there is no camera 1 (camera 0 only)"),
    (("moved-pose=0,200",), "MM must be a number with 0 < MM <= 100"),
    (("silent-speaker=1,7",), "there is no pose 7 (poses 0-2)"),
    (("clipped-bursts=1.5",), "FRACTION must be a number with 0 < FRACTION < 1"),
    (("mjpeg", "mjpeg=90"), "mjpeg is asked for twice"),
    (("dead-mic=3", "inverted-mic=3"), "contradicts 'dead-mic=3'"),
    (("swap-mics=1,2", "swap-mics=2,3"), "contradicts 'swap-mics=1,2'"),
    (("board-shift", "board-shift=-1"), "board-shift is asked for twice"),
    (("swap-speakers=0,1", "swap-speakers=1,2"), "contradicts 'swap-speakers=0,1'"),
    (("silent-speaker=2", "distorted-speaker=2"), "contradicts the silent speaker 2"),
    (("refmic-far=1", "silent-speaker=1"),
     "contradicts the reference microphone misplaced at speaker 1"),
    (("board-shift=4",), "puts every microphone back on its own input"),
    (("swap-speakers=0,1", "refmic-far=1"),
     "contradicts 'swap-speakers=0,1': speaker 1's reference recording is of the other"),
    (("swap-speakers=0,1", "distorted-speaker=1"),
     "contradicts 'swap-speakers=0,1': speaker 1's reference recording is made at the other"),
    (("moved-pose=1", "glare=1,0"), "contradicts the moved pose 1"),
])
def test_a_mistake_the_world_cannot_make_is_refused(mistakes: tuple[str, ...],
                                                    message: str) -> None:
    with pytest.raises(SimulationInputError, match=re.escape(message)) as info:
        build_simulated_capture(_options(*mistakes))
    assert "\n" not in str(info.value)


def test_defaults_are_drawn_from_the_seed_and_alone() -> None:
    """Without arguments a mistake is a seeded, plausible choice: the same for the same seed,
    another for another seed, and not changed by adding another mistake."""
    def records(seed: int, *mistakes: str) -> list[dict]:
        options = _options(*mistakes).model_copy(update={"seed": seed})
        return list(build_simulated_capture(options).mistakes.records)

    first = records(3, "swap-mics", "moved-pose", "close-reflector")
    assert first == records(3, "swap-mics", "moved-pose", "close-reflector")
    assert first != records(4, "swap-mics", "moved-pose", "close-reflector")
    assert records(3, "swap-mics", "moved-pose", "close-reflector", "mjpeg")[:3] == first
    assert first[0]["boards"][0] == first[0]["boards"][1]  # neighbours on one board
    assert abs(first[0]["channels"][0] - first[0]["channels"][1]) == 1
    assert 5 <= first[1]["translation_mm"] <= 20 and 1 <= first[1]["rotation_deg"] <= 3
    assert 10e-6 <= first[2]["delay_s"] <= 20e-6 and 0.3 <= first[2]["gain"] <= 0.5


def test_any_two_mistakes_of_their_defaults_can_be_made_together() -> None:
    """The lead's sweep (issue 33: every mistake alone and two at a time) never meets a
    refusal: a default avoids what another mistake took (a microphone, a speaker, a pose)."""
    from itertools import combinations_with_replacement

    from sim.mistakes import KINDS
    from sim.mistakes.planner import PlanContext, plan_mistakes

    sim = build_simulated_capture(_options())
    context = PlanContext(sim.world.layout, sim.config, sim.world, sim.poses)
    once = {"mjpeg", "clipped-bursts", "board-shift"}
    for a, b in combinations_with_replacement([k.name for k in KINDS], 2):
        if a == b and a in once:
            continue
        records = plan_mistakes((a, b), context).records
        assert [r["kind"] for r in records] == [a, b]


def test_a_speaker_silent_all_session_is_not_drawn_where_the_reference_was_misplaced() -> None:
    """Silent all session, the speaker whose reference microphone stood too far would hide
    that mistake (the grid of every pair drew both on speaker 0 for seed 1): the default draw
    avoids it; silent at some poses only, it may fall there."""
    for seed in range(8):
        options = _options("refmic-far", "silent-speaker").model_copy(update={"seed": seed})
        far, silent = build_simulated_capture(options).mistakes.records
        assert far["speakers"] != silent["speakers"]
    build_simulated_capture(_options("refmic-far=1", "silent-speaker=1,0"))


def test_a_misplaced_reference_microphone_is_not_drawn_at_a_swapped_speaker() -> None:
    """A swapped speaker's reference recording is of the other speaker, a hand's width away,
    which a few millimetres more in front of its own diaphragm cannot change (the grid of
    every pair drew both on speaker 2 for seed 3, and nothing named `refmic-far`): the default
    draw avoids the swapped speakers."""
    for seed in range(8):
        options = _options("swap-speakers", "refmic-far").model_copy(update={"seed": seed})
        swap, far = build_simulated_capture(options).mistakes.records
        assert not set(far["speakers"]) & set(swap["speakers"])


def test_a_distortion_is_not_drawn_at_a_swapped_speaker() -> None:
    """A distortion shows in the speaker's reference recording, made at its diaphragm; a
    swapped speaker's is made at the other speaker (every pair, seed 5, drew the distortion
    on a swapped speaker, and nothing could name it): the default draw avoids them."""
    for seed in range(8):
        options = _options("swap-speakers", "distorted-speaker").model_copy(
            update={"seed": seed})
        swap, distorted = build_simulated_capture(options).mistakes.records
        assert not set(distorted["speakers"]) & set(swap["speakers"])


@pytest.mark.parametrize("image", ["hidden-board", "motion-blur", "glare"])
def test_an_image_mistake_is_not_drawn_at_a_moved_pose(image: str) -> None:
    """A rig moved after its images shows only against a view the calibration measures; a
    view hidden, blurred or in glare is left out, and the pose is placed by its own bursts
    (every pair, seed 5, drew glare at the moved pose, and nothing could name the move)."""
    for seed in range(8):
        options = _options("moved-pose", image).model_copy(update={"seed": seed})
        moved, spoiled = build_simulated_capture(options).mistakes.records
        assert spoiled["poses"] != moved["poses"]


def test_cable_mistakes_compose_and_truth_says_where_each_microphone_ends() -> None:
    swap, shift = build_simulated_capture(_options("swap-mics=12,13", "board-shift")
                                          ).mistakes.records
    assert swap["columns"] == [12, 13] and swap["recorded_in_columns"] == [25, 24]
    assert shift["recorded_in_columns"][12:14] == [25, 24]
    assert shift["recorded_in_columns"][:3] == [12, 13, 14]


def test_without_mistakes_truth_says_none(files: _Files) -> None:
    assert files.truth("clean")["mistakes"] == []
    assert files.truth("clean")["simulation"]["mistakes"] == []
    assert files.truth("mics")["simulation"]["mistakes"] == list(SESSIONS["mics"])


def test_the_configuration_stays_the_nominal_one(files: _Files) -> None:
    for name in SESSIONS:
        assert files.readers[name].capture == files.readers["clean"].capture


# -- what the capture's quality checks see ----------------------------------------------------

def test_the_quality_checks_judge_a_mistake_as_a_lab_recording(files: _Files) -> None:
    """The daemon's checks (acquisition.daemon.quality, default policies) on the mistaken
    sessions' files: clipping and a silent speaker fail with `retry`, a dead microphone is
    warned about, an arm or glare over the only camera's board fails `checkerboard`, a cable
    swap and motion blur pass unseen, as they would on real recordings."""
    config = QualityConfig()
    mics = list(range(N_MICS))
    names = [f"column {j}" for j in range(N_MICS + 1)]

    def failures(session: str, step: str, k: int) -> dict[str, str]:
        codes = files.recording(session, step, k).astype(np.int16)
        levels = measure(codes, 512, 511, config.clip_fraction)
        return {f.check: f.policy for f in judge_recording(levels, mics, mics, True, config,
                                                           names)}

    assert failures("clean", "pose/0000", 0) == {}
    assert failures("clipped", "pose/0000", 0) == {"clipping": "retry"}
    assert failures("speakers", "pose/0001", 4) == {"level": "retry", "snr": "retry",
                                                    "dead_channels": "warn"}
    assert failures("mics", "pose/0000", 0) == {"dead_channels": "warn"}
    assert failures("shift", "pose/0000", 0) == {}
    found = [{"cam0": checkerboard_corners(files.image("images", p), (6, 9)) is not None}
             for p in POSES]
    assert [[f.check for f in judge_images(f, config)] for f in found] == [
        ["checkerboard"], ["checkerboard"], []]  # the arm, the glare, the motion blur


def test_micam_simulate_refuses_a_bad_mistake_in_one_line(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture) -> None:
    from micam.cli import main

    out = tmp_path / "s"
    assert main(["simulate", "--out", str(out), "--quiet", "--array", "scatter48",
                 "--mistake", "dead-mic=72"]) == 2
    err = capsys.readouterr().err
    assert err == ("micam: error: mistake 'dead-mic=72': there is no microphone 72 "
                   "(microphones 0-47)\n")
    assert not out.exists()  # nothing was recorded


def test_micam_simulate_help_lists_every_mistake(capsys: pytest.CaptureFixture) -> None:
    from micam.cli import main
    from sim.mistakes import KINDS

    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    lines = capsys.readouterr().out.splitlines()
    for kind in KINDS:
        assert sum(line.split()[:1] == [kind.usage] for line in lines) == 1
