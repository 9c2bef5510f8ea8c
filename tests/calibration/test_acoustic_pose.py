"""calibration.solve.acoustic_pose on a synthetic array and rig: a pose no camera located is
placed by its times of flight, with a covariance that covers its error, and a pose that no
rigid placement explains is not placed."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.solve.acoustic_pose import place_rig
from kernel.rigid import RigidTransform

C = 343.0
NOISE_S = 0.3e-6
SPEAKERS_RIG_M = np.array([[-0.15, -0.1, 0.0], [0.0, -0.1, 0.0], [0.15, -0.1, 0.0],
                           [-0.15, 0.1, 0.0], [0.0, 0.1, 0.0], [0.15, 0.1, 0.0]])
TRUE = RigidTransform.from_rotvec(np.array([0.1, -0.2, 0.05]), np.array([0.05, -0.02, 0.6]))


def _scene(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(microphones (48, 3), latencies (48,), times of flight (6, 48)) of the true pose: a
    0.4 m array about the camera, two boards' latencies, 0.3 us of noise."""
    rng = np.random.default_rng(seed)
    microphones = rng.uniform(-0.2, 0.2, (48, 3)) * [1.0, 1.0, 0.1]
    latency = np.repeat([20e-6, 23e-6], 24)
    distance = np.linalg.norm(microphones[None] - TRUE.apply(SPEAKERS_RIG_M)[:, None], axis=2)
    tof = distance / C + latency + rng.normal(0.0, NOISE_S, distance.shape)
    return microphones, latency, tof


def _starts() -> list[RigidTransform]:
    """Two located poses: one 0.2 m and 0.5 rad away, one 5 cm and 0.1 rad away."""
    return [RigidTransform.from_rotvec(np.array([0.6, -0.2, 0.05]), np.array([0.25, 0.0, 0.8])),
            RigidTransform.from_rotvec(np.array([0.0, -0.15, 0.0]), np.array([0.0, 0.0, 0.6]))]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_pose_is_placed_by_its_times_of_flight_within_its_stated_covariance(seed: int) -> None:
    microphones, latency, tof = _scene(seed)
    tof[0, :5] = np.nan  # not heard
    tof[2, 7] += 80e-6  # a reflection picked instead of the direct sound
    pose = place_rig(tof, microphones, latency, C, SPEAKERS_RIG_M, _starts(), NOISE_S)
    assert pose is not None
    error = pose.transform.params - TRUE.params
    assert np.all(np.abs(error[3:]) < 50e-6)  # within 50 um, 0.3 us of noise on 48 x 6
    sigma = np.sqrt(np.diag(pose.cov))
    assert np.all(sigma[:3] < 0.5e-3) and np.all(sigma[3:] < 50e-6)  # rad, m
    assert np.all(sigma > 0)
    assert np.all(np.abs(error) < 4.0 * sigma), (error / sigma)


def test_times_of_flight_no_rigid_rig_explains_place_nothing() -> None:
    """Half of the speakers' times of flight from a rig 10 cm away (two poses' bursts mixed);
    three speakers heard by too few microphones, or no typical residual: not placed."""
    microphones, latency, tof = _scene(4)
    elsewhere = RigidTransform.from_rotvec(TRUE.rotvec, TRUE.t + [0.1, 0.0, 0.0])
    moved = np.linalg.norm(microphones[None] - elsewhere.apply(SPEAKERS_RIG_M)[:, None], axis=2)
    mixed = tof.copy()
    mixed[3:] = moved[3:] / C + latency
    assert place_rig(mixed, microphones, latency, C, SPEAKERS_RIG_M, _starts(), NOISE_S) is None
    few = tof.copy()
    few[:4, 3:] = np.nan  # four speakers heard by three microphones: two speakers left
    assert place_rig(few, microphones, latency, C, SPEAKERS_RIG_M, _starts(), NOISE_S) is None
    # no located pose's residual to judge the fit against: nothing placed (it once raised)
    assert place_rig(tof, microphones, latency, C, SPEAKERS_RIG_M, _starts(), np.nan) is None
