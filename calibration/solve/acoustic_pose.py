"""A rig pose that no camera located, placed by its own times of flight.

Why: a pose whose board the cameras did not find (motion blur, glare, a hidden board, a
camera that returned no frame) loses its bursts as well as its corners when the rig's pose is
taken from the images alone. One pose fewer of 20 cost the realistic lab 1.03-1.28x of its
error on seed 5, two poses 1.58-1.70x. Yet six speakers heard by dozens of microphones fix
the rig's six unknowns many times over: with the microphones, their latencies and c from the
located poses, the pose that best explains its own times of flight is found by least squares
and given to the joint fit as a board pose without corners, where its times of flight alone
hold it (calibration.solve.bundle). Nothing of the cameras' is invented: the pose's images
stay out.

A pose whose times of flight do not fit any rigid placement of the rig (a speaker moved on
it, a wrong rig description) is not placed: its fit's median |residual| must lie within
`PLACED_RESIDUAL_RATIO` of the located poses'.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.optimize import least_squares

from kernel.rigid import RigidTransform

from ..camera.camera_calibration import Pose
from .robust import MAD_TO_SIGMA

MIN_SPEAKERS = 3
"""Fewest speakers heard at a pose that fix its rotation (three not on a line)."""

OUTLIER_SIGMAS = 5.0
"""Times of flight beyond this many robust sigmas of the fit (a reflection picked) do not
count in its covariance."""

PLACED_RESIDUAL_RATIO = 3.0
"""A pose is placed when its fit's median |residual| is at most this many times the median
|residual| of the located poses' times of flight: a rig that fits its bursts as well as the
seen ones do."""


def place_rig(tof_s: np.ndarray, microphones_m: np.ndarray, latency_s: np.ndarray,
              speed_of_sound_m_s: float, speakers_rig_m: np.ndarray,
              starts: list[RigidTransform], typical_residual_s: float) -> Pose | None:
    """The rig's pose (rig -> camera 0, with the (6, 6) covariance of its (rotvec, t)) that
    its times of flight put it at, or None when they fit no rigid placement as well as the
    located poses' do (`PLACED_RESIDUAL_RATIO`).

    Args:
        tof_s: (S, M) the pose's times of flight, NaN where missing.
        microphones_m: (M, 3) the microphones in the camera-0 frame (NaN: not solved).
        latency_s: (M,) each microphone's board latency, seconds.
        speed_of_sound_m_s: c.
        speakers_rig_m: (S, 3) the speakers on the rig, rig frame.
        starts: rig poses to start from (the located poses'): the fit starts from the one
            whose times of flight come closest.
        typical_residual_s: the located poses' median |residual|, seconds.
    """
    usable = np.isfinite(tof_s) & np.all(np.isfinite(microphones_m), axis=1)[None, :]
    speakers = np.flatnonzero(usable.sum(axis=1) >= 4)
    if speakers.size < MIN_SPEAKERS or not starts or not np.isfinite(typical_residual_s):
        return None  # (a NaN typical residual: nothing to judge the placement against)
    spk, mic = np.nonzero(usable[speakers])
    spk = speakers[spk]
    measured = tof_s[spk, mic] - latency_s[mic]

    def residual(params: np.ndarray) -> np.ndarray:
        rig = RigidTransform.from_rotvec(params[:3], params[3:])
        sources = rig.apply(speakers_rig_m)
        flight = np.linalg.norm(microphones_m[mic] - sources[spk], axis=1) / speed_of_sound_m_s
        return flight - measured

    start = min((s.params for s in starts), key=lambda p: float(np.median(np.abs(residual(p)))))
    scale = max(typical_residual_s, 1e-9)
    fit = least_squares(lambda p: residual(p) / scale, start, loss="soft_l1", f_scale=3.0,
                        x_scale=np.array([1e-2, 1e-2, 1e-2, 1e-3, 1e-3, 1e-3]))
    final = residual(fit.x)
    if not np.median(np.abs(final)) <= PLACED_RESIDUAL_RATIO * typical_residual_s:
        return None
    inliers = np.abs(final) <= OUTLIER_SIGMAS * MAD_TO_SIGMA * np.median(np.abs(final))
    jacobian = _jacobian(residual, fit.x)[inliers]  # d residual (s) / d (rotvec, t)
    variance = float(np.sum(final[inliers] ** 2) / max(int(inliers.sum()) - 6, 1))
    cov = np.linalg.pinv(jacobian.T @ jacobian) * variance
    return Pose(RigidTransform.from_rotvec(fit.x[:3], fit.x[3:]), cov)


def _jacobian(residual: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> np.ndarray:
    """(n, 6) central differences of `residual` at the pose `x` (1 urad, 1 um steps)."""
    columns = []
    for k in range(x.size):
        step = np.zeros_like(x)
        step[k] = 1e-6
        columns.append((residual(x + step) - residual(x - step)) / 2e-6)
    return np.stack(columns, axis=1)
