"""Speaker and reference-microphone positions in the camera-0 frame (paper section IV-E).

A rig point with rig-frame coordinates X_rig lies at X_cam = R X_rig + T in the frame of a
camera whose image gave the board pose (R, T) (paper equation 10). The calibration's frame is
camera 0's, so a pose seen by camera 0 is used as it is; a pose seen only by another camera
is carried into the camera-0 frame through that camera's transform from camera 0.

Uncertainty: the 6x6 covariance of the pose (rotation vector, translation) is propagated to
every point by the Jacobian of the point with respect to the pose, evaluated by central
differences (the same code for poses carried between cameras, where the rotation vector of a
composed rotation has no convenient closed-form derivative). The cameras' transforms from
camera 0 are taken as exact: their errors (about 0.03 degrees and 0.1 mm on the simulated
sessions) are not in the covariances of poses carried through them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from acquisition.contracts.step_ids import REFMIC_STEP, is_pose_step
from kernel.rigid import RigidTransform

from .camera_calibration import CameraCalibration, Pose
from ..errors import CalibrationInputError

_STEP_RAD_OR_M = 1e-6
"""Central-difference step for the pose parameters (radians and metres): small against the
pose uncertainty (~1e-4), large against rounding (~1e-16 relative)."""


class SpeakerLocationError(CalibrationInputError):
    """A rig point cannot be located (no calibrated camera saw the board)."""


@dataclass(frozen=True)
class RigPoseInCam0:
    """The rig's pose in the camera-0 frame for one session step.

    Attributes:
        step: the session step ("pose/0003", "refmic").
        camera: the camera whose image located the rig.
        rig_to_cam0: x_cam0 = R x_rig + t, with the (6, 6) covariance of its
            (rotvec, t) in the camera-0 frame.
        rms_px: RMS reprojection error of that image, pixels.
    """

    step: str
    camera: str
    rig_to_cam0: Pose
    rms_px: float

    def locate(self, points_rig_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rig points (n, 3) in the camera-0 frame (n, 3), metres, and their (n, 3, 3)
        covariances, m^2 (paper equation 10)."""
        points = np.asarray(points_rig_m, dtype=np.float64).reshape(-1, 3)
        pose = self.rig_to_cam0
        cov = _propagate(lambda p: _transform(p).apply(points).ravel(), pose.transform.params,
                         pose.cov)
        n = len(points)
        blocks = cov.reshape(n, 3, n, 3)[np.arange(n), :, np.arange(n), :]
        return pose.transform.apply(points), blocks


@dataclass(frozen=True)
class SpeakerPositions:
    """Speaker positions of every located rig pose, in the camera-0 frame.

    Attributes:
        poses: the rig pose of each located step, in step order.
        positions_m: (n_poses, n_speakers, 3) speaker positions, metres.
        cov_m2: (n_poses, n_speakers, 3, 3) their covariances, m^2.
        unlocated: pose steps no calibrated camera found the board in (skipped).
    """

    poses: list[RigPoseInCam0]
    positions_m: np.ndarray
    cov_m2: np.ndarray
    unlocated: list[str]

    @property
    def steps(self) -> list[str]:
        return [p.step for p in self.poses]


@dataclass(frozen=True)
class ReferenceMicrophonePosition:
    """The reference microphone on its stand, in the camera-0 frame.

    Attributes:
        position_m: (3,) position, metres: the rig's reference mark touching it.
        cov_m2: (3, 3) covariance, m^2.
        pose: the rig pose of the "refmic" step that located it.
    """

    position_m: np.ndarray
    cov_m2: np.ndarray
    pose: RigPoseInCam0


def rig_pose_in_cam0(calibration: CameraCalibration, step: str) -> RigPoseInCam0 | None:
    """The rig's pose in the camera-0 frame from the best view of `step`, or None if no
    calibrated camera found the board.

    Camera 0's own view is preferred (no camera-to-camera transform, whose error the
    covariance leaves out); otherwise the view whose translation is the most certain.
    """
    views = calibration.views_of_step(step)
    if not views:
        return None
    reference = calibration.reference_camera
    own = [v for v in views if v.camera == reference]
    view = own[0] if own else min(views, key=lambda v: np.trace(v.rig_to_cam.cov[3:, 3:]))
    pose = (
        view.rig_to_cam
        if view.camera == reference
        else _to_cam0(view.rig_to_cam, calibration.cam_from_cam0[view.camera].cam0_to_cam)
    )
    return RigPoseInCam0(step, view.camera, pose, view.rms_px)


def speaker_positions(
    calibration: CameraCalibration,
    speakers_rig_m: np.ndarray,
    steps: Iterable[str] | None = None,
) -> SpeakerPositions:
    """Every speaker's position in the camera-0 frame for every rig pose (paper eq. 10).

    Args:
        calibration: the cameras' calibration.
        speakers_rig_m: (n_speakers, 3) speaker positions in the rig frame, metres, in
            speaker-index order (the capture configuration's `speakers[k].rig_position_m`).
        steps: the pose steps to locate; by default every "pose/..." step with a board view.
            Steps without one are listed in `unlocated`.

    Raises:
        SpeakerLocationError: no step could be located.
    """
    speakers = np.asarray(speakers_rig_m, dtype=np.float64).reshape(-1, 3)
    if steps is None:
        steps = {s for _, s in calibration.views if is_pose_step(s)}
    poses = {step: rig_pose_in_cam0(calibration, step) for step in sorted(steps)}
    located = [p for p in poses.values() if p is not None]
    unlocated = [step for step, p in poses.items() if p is None]
    if not located:
        raise SpeakerLocationError(
            f"none of the {len(unlocated)} pose steps has a board view from a calibrated "
            "camera, so no speaker can be located"
        )
    points = [p.locate(speakers) for p in located]
    return SpeakerPositions(
        poses=located,
        positions_m=np.stack([x for x, _ in points]),
        cov_m2=np.stack([c for _, c in points]),
        unlocated=unlocated,
    )


def reference_microphone_position(
    calibration: CameraCalibration, reference_mark_rig_m: np.ndarray, step: str = REFMIC_STEP
) -> ReferenceMicrophonePosition:
    """The reference microphone's position: the rig's reference mark in the camera-0 frame,
    from the image taken with the mark touching the microphone (paper IV-C).

    Raises:
        SpeakerLocationError: no calibrated camera found the board in `step`'s images.
    """
    pose = rig_pose_in_cam0(calibration, step)
    if pose is None:
        raise SpeakerLocationError(
            f"no calibrated camera found the checkerboard in the {step!r} images, so the "
            "reference microphone cannot be located; retake that step with the board in view"
        )
    position, cov = pose.locate(np.asarray(reference_mark_rig_m, dtype=np.float64))
    return ReferenceMicrophonePosition(position[0], cov[0], pose)


def _to_cam0(rig_to_cam: Pose, cam0_to_cam: RigidTransform) -> Pose:
    """A board pose in another camera's frame carried into the camera-0 frame, with its
    covariance.

    x_cam0 = A^-1 (R x_rig + t) with A = cam0_to_cam, so R0 = A_R^T R, t0 = A_R^T (t - A_t).
    The rotation vector of R0 comes from scipy (quaternion-based): cv2.Rodrigues loses about
    half the digits of the axis within 1e-5 rad of a half turn, where boards facing the
    camera are.
    """
    params = rig_to_cam.transform.params

    def compose(p: np.ndarray) -> np.ndarray:
        return cam0_to_cam.inverse_compose(_transform(p)).params

    composed = compose(params)
    # Keep every perturbed rotation vector on the branch of the composed one: near a half
    # turn (a board facing the camera is one) Rodrigues may return the equivalent vector of
    # angle theta - 2 pi, which would wreck the differences.
    cov = _propagate(lambda p: _same_branch(compose(p), composed), params, rig_to_cam.cov)
    return Pose(_transform(composed), cov)


def _same_branch(params: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(rvec, t) with rvec replaced by its equivalent r (1 - 2 pi / |r|) if that is nearer
    to the reference rotation vector."""
    rvec = params[:3]
    angle = np.linalg.norm(rvec)
    if angle > 0:
        alternative = rvec * (1.0 - 2.0 * np.pi / angle)
        if np.linalg.norm(alternative - reference[:3]) < np.linalg.norm(rvec - reference[:3]):
            return np.concatenate([alternative, params[3:]])
    return params


def _transform(params: np.ndarray) -> RigidTransform:
    """The transform of pose parameters (rotvec, t), radians and metres."""
    return RigidTransform.from_rotvec(params[:3], params[3:])


def _propagate(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """First-order covariance J cov J^T of f(x), J by central differences."""
    columns = []
    for k in range(x.size):
        dx = np.zeros_like(x)
        dx[k] = _STEP_RAD_OR_M
        columns.append((f(x + dx) - f(x - dx)) / (2 * _STEP_RAD_OR_M))
    J = np.stack(columns, axis=1)
    return J @ cov @ J.T
