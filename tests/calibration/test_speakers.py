"""calibration.camera.speakers against the truth of a small simulated session (12 poses).

Tolerance 1 mm on speakers and the reference microphone (the issue asks ~2 mm): the board
poses are good to ~0.25 mm (mostly the focal-length error scaling depth) and the speakers sit
0.1-0.15 m from the pattern, which amplifies the ~0.01 degree rotation errors to ~0.03 mm;
a swapped speaker (1<->4) would be off by ~300 mm, a mirrored frame by 5 mm or more.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.contracts.session import SessionReader
from calibration.camera.camera_calibration import (
    CameraCalibration,
    Checkerboard,
    Extrinsics,
    Pose,
    calibrate_session,
)
from calibration.session_data import load_session
from calibration.camera.speakers import (
    RigPoseInCam0,
    SpeakerLocationError,
    reference_microphone_position,
    rig_pose_in_cam0,
    speaker_positions,
)
from kernel.rigid import RigidTransform

pytestmark = pytest.mark.slow  # every test here: the twelve-pose session and its camera calibration


@dataclasses.dataclass(frozen=True)
class Setup:
    reader: SessionReader
    truth: dict
    calibration: CameraCalibration
    speakers_rig_m: np.ndarray
    pose_steps: list[str]


@pytest.fixture(scope="module")
def setup(twelve_pose_session: Path) -> Setup:
    out = twelve_pose_session
    reader = SessionReader(out)
    speakers = sorted(reader.capture["speakers"], key=lambda s: s["index"])
    return Setup(
        reader=reader,
        truth=json.loads(Path(out, "truth.json").read_text()),
        calibration=calibrate_session(reader, Checkerboard.of_rig(load_session(out).rig),
                                      ["cam0", "cam1", "cam2"]),
        speakers_rig_m=np.array([s["rig_position_m"] for s in speakers]),
        pose_steps=sorted(s for s in reader.steps() if s.startswith("pose/")),
    )


def _true_speakers(truth: dict, step: str) -> np.ndarray:
    return np.array(truth["poses"][int(step.split("/")[1])]["speakers_m"])


def test_speaker_positions_match_truth(setup: Setup) -> None:
    located = speaker_positions(setup.calibration, setup.speakers_rig_m, setup.pose_steps)
    assert located.steps == setup.pose_steps and not located.unlocated
    for step, positions, cov in zip(
        located.steps, located.positions_m, located.cov_m2, strict=True
    ):
        true = _true_speakers(setup.truth, step)
        error = np.linalg.norm(positions - true, axis=1)
        assert error.max() < 1e-3, (step, error)
        # Each speaker is nearest its own true position: the half-turn ambiguity is resolved.
        nearest = np.linalg.norm(positions[:, None] - true[None], axis=2).argmin(axis=1)
        assert np.array_equal(nearest, np.arange(len(true)))
        std = np.sqrt(np.einsum("sii->si", cov))
        assert np.all(np.abs(positions - true) < 5 * std), (step, positions - true, std)


def test_reference_microphone_matches_truth(setup: Setup) -> None:
    mark = setup.reader.capture["rig"]["reference_mark_m"]
    ref = reference_microphone_position(setup.calibration, mark)
    true = np.array(setup.truth["reference_microphone"]["stand_position_m"])
    assert np.linalg.norm(ref.position_m - true) < 1e-3
    assert ref.pose.camera == "cam0" and ref.cov_m2.shape == (3, 3)


def test_poses_seen_only_by_another_camera_go_through_its_extrinsics(setup: Setup) -> None:
    """Drop camera 0's views of the steps cam1 also saw: those poses must come from cam1."""
    calibration = setup.calibration
    shared = sorted(s for c, s in calibration.views if c == "cam1" and s.startswith("pose/"))
    assert len(shared) >= 2
    without_cam0 = dataclasses.replace(
        calibration,
        views={
            k: v for k, v in calibration.views.items() if not (k[0] == "cam0" and k[1] in shared)
        },
    )
    located = speaker_positions(without_cam0, setup.speakers_rig_m, shared)
    for pose, positions in zip(located.poses, located.positions_m, strict=True):
        assert pose.camera == "cam1"
        error = np.linalg.norm(positions - _true_speakers(setup.truth, pose.step), axis=1)
        assert error.max() < 1e-3, (pose.step, error)


def test_covariance_is_frame_covariant_through_extrinsics(setup: Setup) -> None:
    """A pose carried into another frame keeps its point covariances, rotated: C0 = A^T C A.

    The carried rotation is an exact half turn (a board squarely facing camera 0), where
    Rodrigues switches between equivalent rotation vectors: the differences must stay on one
    branch.
    """
    view = setup.calibration.views[("cam0", "pose/0000")]
    R_a = cv2.Rodrigues(np.array([0.1, 0.5, -0.2]))[0]
    cam0_to_camx = RigidTransform(R_a, np.array([0.07, 0.01, -0.02]))
    ext = Extrinsics(cam0_to_camx, 0.0, 2, "cam0")
    rvec = cv2.Rodrigues(R_a @ np.diag([1.0, -1.0, -1.0]))[0].ravel()
    pose = Pose(RigidTransform.from_rotvec(rvec, np.array([-0.1, 0.05, 0.8])),
                view.rig_to_cam.cov)
    calibration = dataclasses.replace(
        setup.calibration,
        intrinsics={**setup.calibration.intrinsics, "camX": setup.calibration.intrinsics["cam0"]},
        cam_from_cam0={**setup.calibration.cam_from_cam0, "camX": ext},
        views={("camX", "x"): dataclasses.replace(view, camera="camX", step="x", rig_to_cam=pose)},
    )
    carried = rig_pose_in_cam0(calibration, "x")
    assert carried is not None and carried.camera == "camX"
    assert np.isclose(np.linalg.norm(carried.rig_to_cam0.transform.rotvec), np.pi)
    p_cam, c_cam = RigPoseInCam0("x", "camX", pose, 0.0).locate(setup.speakers_rig_m)
    p_0, c_0 = carried.locate(setup.speakers_rig_m)
    np.testing.assert_allclose(p_0, cam0_to_camx.inverse_apply(p_cam), atol=1e-12)
    expected = np.einsum("ji,sjk,kl->sil", R_a, c_cam, R_a)
    np.testing.assert_allclose(c_0, expected, rtol=1e-4, atol=1e-16)


def test_point_covariance_from_rotation_and_translation() -> None:
    """At rvec = 0, R(r) x + t = x + r x x + t: cov = s_t^2 I + s_r^2 (|x|^2 I - x x^T)."""
    s_r, s_t = 1e-3, 2e-4
    cov = np.diag([s_r**2] * 3 + [s_t**2] * 3)
    pose = RigPoseInCam0("p", "cam0", Pose(RigidTransform.identity(), cov), 0.0)
    x = np.array([0.21, 0.12, -0.0025])
    _, c = pose.locate(x)
    expected = s_t**2 * np.eye(3) + s_r**2 * (x @ x * np.eye(3) - np.outer(x, x))
    np.testing.assert_allclose(c[0], expected, rtol=1e-6)


def test_unlocated_steps_are_reported_and_none_is_an_error(setup: Setup) -> None:
    located = speaker_positions(setup.calibration, setup.speakers_rig_m, ["pose/0000", "pose/9999"])
    assert located.steps == ["pose/0000"] and located.unlocated == ["pose/9999"]
    with pytest.raises(SpeakerLocationError, match="none of the 1 pose steps"):
        speaker_positions(setup.calibration, setup.speakers_rig_m, ["pose/9999"])
    with pytest.raises(SpeakerLocationError, match="reference microphone cannot be located"):
        reference_microphone_position(setup.calibration, np.zeros(3), step="pose/9999")
