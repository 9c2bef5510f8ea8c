"""Rig poses in view of a camera, within a chosen distance range."""

from __future__ import annotations

import numpy as np

from .errors import SimulationInputError
from .geometry import CameraModel, Rig, RigidTransform, rotation_from_rotvec

FACING_CAMERA = np.diag([1.0, -1.0, -1.0])
"""Rig orientation that faces camera 0 squarely: rig X along camera x, rig Y up (camera -y),
rig Z (out of the printed face) towards the camera (camera -z)."""


class PoseSamplingError(SimulationInputError):
    """No pose satisfies the constraints (distance range too small for the image, say)."""


def rig_points(rig: Rig) -> np.ndarray:
    """The rig points that must be in view: every inner corner and every speaker."""
    return np.vstack([rig.corner_points(), rig.speakers_m])


def in_view(camera: CameraModel, points_cam0: np.ndarray, margin_px: float) -> bool:
    """True if every point is in front of the camera and projects inside the image with a margin."""
    if not np.all(camera.in_front(points_cam0)):
        return False
    px = camera.project(points_cam0)
    return bool(
        np.all(px[:, 0] >= margin_px) and np.all(px[:, 0] <= camera.width - 1 - margin_px)
        and np.all(px[:, 1] >= margin_px) and np.all(px[:, 1] <= camera.height - 1 - margin_px)
    )


def sample_pose(
    camera: CameraModel,
    rig: Rig,
    distance_m: tuple[float, float],
    rng: np.random.Generator,
    max_tilt_deg: float = 40.0,
    max_roll_deg: float = 30.0,
    margin_px: float = 40.0,
    max_tries: int = 2000,
) -> RigidTransform:
    """One random rig pose (rig -> camera-0 frame) with the pattern centre at a distance in
    `distance_m` from camera 0's centre, tilted up to `max_tilt_deg` about an in-plane axis,
    rolled up to `max_roll_deg`, and every corner and speaker in view of `camera`."""
    lo, hi = distance_m
    if not 0 < lo <= hi:
        raise PoseSamplingError(f"distance range {distance_m} must satisfy 0 < min <= max")
    K_inv = np.linalg.inv(camera.K)
    for _ in range(max_tries):
        d = rng.uniform(lo, hi)
        u = rng.uniform(0.2, 0.8) * camera.width
        v = rng.uniform(0.2, 0.8) * camera.height
        ray = K_inv @ np.array([u, v, 1.0])
        centre_cam = camera.cam0_to_cam.inverse().apply(d * ray / np.linalg.norm(ray))
        roll_angle = np.radians(rng.uniform(-max_roll_deg, max_roll_deg))
        roll = rotation_from_rotvec(np.array([0.0, 0.0, roll_angle]))
        axis_angle = rng.uniform(0, 2 * np.pi)
        tilt = np.radians(rng.uniform(0, max_tilt_deg))
        tilt_R = rotation_from_rotvec(tilt * np.array([np.cos(axis_angle), np.sin(axis_angle), 0]))
        R = FACING_CAMERA @ tilt_R @ roll
        t = centre_cam - R @ rig.centre()
        pose = RigidTransform(R, t)
        if in_view(camera, pose.apply(rig_points(rig)), margin_px):
            return pose
    raise PoseSamplingError(
        f"no rig pose at {lo}-{hi} m keeps the whole rig in view of {camera.name} after "
        f"{max_tries} tries; widen the distance range or move it further away"
    )


def sample_poses(camera: CameraModel, rig: Rig, n: int, distance_m: tuple[float, float],
                 rng: np.random.Generator) -> list[RigidTransform]:
    """`n` independent random poses (see `sample_pose`)."""
    return [sample_pose(camera, rig, distance_m, rng) for _ in range(n)]
