"""Synthetic calibration scenes for the solver and bound tests (no simulator dependency).

72 microphones on a 0.15 m Fibonacci sphere whose front pole is the camera (origin, z
forward); rig poses 0.6-1.0 m away inside a 20 degree cone, facing the camera with up to 45
degrees of tilt and random roll; six speakers per pose at the paper's Table I coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.solve.solver import RigSources

C_TRUE = 343.2
PAPER_SPEAKERS_M = 1e-3 * np.array(
    [[-60, 0, -2.5], [210, 0, -2.5], [-60, 240, -2.5], [210, 240, -2.5], [-60, 120, -2.5],
     [210, 120, -2.5]]
)  # fmt: skip


def fibonacci_sphere(n: int = 72, radius: float = 0.15) -> np.ndarray:
    """(n, 3) points on a sphere whose +z pole is at the origin (centre at z = -radius)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5**0.5) * i
    rho = np.sqrt(1.0 - z**2)
    unit = np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=1)
    return radius * unit - np.array([0.0, 0.0, radius])


def random_poses(n_pose: int, rng: np.random.Generator, distance=(0.6, 1.0)):
    """Rotation vectors and translations (rig -> camera) of boards facing the camera."""
    rotvecs, translations = [], []
    centre_rig = PAPER_SPEAKERS_M.mean(axis=0)
    for _ in range(n_pose):
        cone = np.deg2rad(20.0) * np.sqrt(rng.uniform())
        azimuth = rng.uniform(0, 2 * np.pi)
        direction = np.array([np.sin(cone) * np.cos(azimuth), np.sin(cone) * np.sin(azimuth),
                              np.cos(cone)])  # fmt: skip
        centre = rng.uniform(*distance) * direction
        # Board normal (rig +Z) towards the camera, tilted up to 45 degrees, random roll.
        facing = Rotation.align_vectors([-direction], [[0.0, 0.0, 1.0]])[0]
        tilt_axis = np.array(
            [np.cos(rng.uniform(0, 2 * np.pi)), np.sin(rng.uniform(0, 2 * np.pi)), 0]
        )
        tilt = Rotation.from_rotvec(
            np.deg2rad(45.0) * np.sqrt(rng.uniform()) * tilt_axis / np.linalg.norm(tilt_axis)
        )
        roll = Rotation.from_rotvec([0.0, 0.0, rng.uniform(0, 2 * np.pi)])
        R = facing * tilt * roll
        rotvecs.append(R.as_rotvec())
        translations.append(centre - R.apply(centre_rig))
    return np.array(rotvecs), np.array(translations)


@dataclass
class Scene:
    mics: np.ndarray  # (n_mic, 3) truth
    true_sources: RigSources  # exact poses
    measured_sources: RigSources  # camera estimate (noisy poses / positions)
    measured_positions: np.ndarray  # (n_src, 3) camera estimate of every source
    tof: np.ndarray  # (n_src, n_mic)
    board_of_mic: np.ndarray


def make_scene(
    n_pose: int,
    seed: int,
    sigma_t: float = 1e-6,
    sigma_p: float = 0.0,
    pose_std: tuple[float, float] = (0.0, 0.0),
    latency_of_board: tuple[float, ...] = (0.0,),
    outlier_fraction: float = 0.0,
    distance=(0.6, 1.0),
) -> Scene:
    """A scene with timing noise sigma_t (s), i.i.d. source noise sigma_p (m per axis),
    rigid per-pose camera errors of pose_std = (rotation rad, translation m) per axis,
    board latencies (s; mics are dealt to boards round-robin) and reflection outliers
    (+0.3..3 ms) on a fraction of the TOFs."""
    rng = np.random.default_rng(seed)
    mics = fibonacci_sphere()
    rotvec, trans = random_poses(n_pose, rng, distance)
    pose_of_source = np.repeat(np.arange(n_pose), 6)
    speaker = np.tile(np.arange(6), n_pose)
    cov = np.diag(
        np.r_[np.full(3, max(pose_std[0], 1e-9) ** 2), np.full(3, max(pose_std[1], 1e-9) ** 2)]
    )
    true = RigSources(
        PAPER_SPEAKERS_M, rotvec, trans, pose_of_source, speaker, np.repeat(cov[None], n_pose, 0)
    )
    noisy_rot = rotvec + pose_std[0] * rng.standard_normal(rotvec.shape)
    noisy_trans = trans + pose_std[1] * rng.standard_normal(trans.shape)
    measured = RigSources(PAPER_SPEAKERS_M, noisy_rot, noisy_trans, pose_of_source, speaker,
                          true.pose_covariance)  # fmt: skip
    positions = measured.positions() + sigma_p * rng.standard_normal((6 * n_pose, 3))

    board = np.arange(mics.shape[0]) % len(latency_of_board)
    dist = np.linalg.norm(mics[None] - true.positions()[:, None], axis=-1)
    tof = (
        dist / C_TRUE
        + np.asarray(latency_of_board)[board]
        + sigma_t * rng.standard_normal(dist.shape)
    )
    outliers = rng.uniform(size=tof.shape) < outlier_fraction
    tof[outliers] += rng.uniform(0.3e-3, 3e-3, outliers.sum())
    return Scene(mics, true, measured, positions, tof, board)


def mean_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Mean Euclidean error over microphones, metres."""
    return float(np.mean(np.linalg.norm(estimate - truth, axis=1)))
