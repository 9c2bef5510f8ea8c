"""The live calibration after a pose: where each microphone is so far, how well it is known,
what accuracy the poses taken predict, and where one more pose would help most.

- mean uncertainty: the mean over microphones of E|error| from the solver's covariance (the
  camera-frozen fit of the poses so far, scaled by its residuals);
- predicted accuracy: the mean E|error| of the per-microphone Cramer-Rao bound
  (calibration.solve.crlb.mic_position_crlb) for these sources, with the measured timing noise and
  the cameras' source-position noise. It ignores the errors the microphones share (c, the
  camera's scale), so it is what the joint final fit approaches, not a guarantee;
- suggestion: of a grid of rig positions in camera 0's view (azimuth, elevation, distance
  around the distances used so far, rig facing the camera; positions where the board would
  leave camera 0's image are skipped), the one whose speakers lower the predicted mean error
  most. The operator can stop when the prediction meets the target.
  It carries the board's outline and the speakers at that pose projected into camera 0's
  image, so that a page can draw where to hold the rig;
- poses taken: where the rig's centre was at each pose used (distance, azimuth, elevation from
  camera 0), the coverage so far.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from acquisition.contracts.job_messages import (
    LiveMicrophone,
    LiveUpdate,
    PoseSuggestion,
    PoseTaken,
)
from kernel.rigid import RigidTransform

from ..solve.crlb import expected_error_norm, mic_position_crlb
from ..pipeline import Measurements
from ..solve.solver import MicrophoneSolution

AZIMUTHS_DEG = (-30.0, -15.0, 0.0, 15.0, 30.0)
ELEVATIONS_DEG = (-20.0, 0.0, 20.0)


def live_update(session_id: str, m: Measurements, sol: MicrophoneSolution) -> LiveUpdate:
    """The live update of a camera-frozen solution `sol` of the measurements `m`."""
    valid = np.all(np.isfinite(sol.positions_m), axis=1) & np.all(
        np.isfinite(sol.covariance_m2), axis=(1, 2))
    mics = sol.positions_m[valid]
    std = np.sqrt(np.maximum(np.diagonal(sol.covariance_m2, axis1=1, axis2=2), 0.0))
    microphones = [LiveMicrophone(id=int(i), position_m=_vec(p), std_m=_vec(s))
                   for i, p, s, ok in zip(m.data.mic_ids, sol.positions_m, std, valid,
                                          strict=True) if ok]
    sources = m.speakers.positions_m.reshape(-1, 3)
    timing = m.tofs.std_s[m.located]
    timing_std = float(np.nanmedian(timing[np.isfinite(timing)])) * max(sol.sigma_scale, 1.0)
    source_var = np.trace(m.speakers.cov_m2, axis1=-2, axis2=-1).reshape(-1) / 3.0
    source_std = float(np.sqrt(np.median(source_var)))
    c = sol.speed_of_sound_m_s

    def predicted(extra: np.ndarray | None = None) -> float:
        points = sources if extra is None else np.vstack([sources, extra])
        bound = mic_position_crlb(mics, points, c, timing_std, source_std)
        return float(expected_error_norm(bound).mean())

    camera = m.cameras.intrinsics[m.cameras.reference_camera]
    return LiveUpdate(
        session_id=session_id, poses=len(m.located), microphones=microphones,
        mean_uncertainty_m=float(expected_error_norm(sol.covariance_m2[valid]).mean()),
        predicted_accuracy_m=predicted(), speed_of_sound_m_s=c,
        suggestion=_best_pose(m, predicted), image_size=(camera.width, camera.height),
        poses_taken=_poses_taken(m))


def _angles(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance (m), azimuth (deg, right positive) and elevation (deg, up positive) of points
    (n, 3) in the camera-0 frame: the inverse of the suggestion's `direction`."""
    distance = np.linalg.norm(points, axis=1)
    azimuth = np.degrees(np.arctan2(points[:, 0], points[:, 2]))
    elevation = np.degrees(np.arcsin(np.clip(-points[:, 1] / distance, -1.0, 1.0)))
    return distance, azimuth, elevation


def _poses_taken(m: Measurements) -> list[PoseTaken]:
    """Where the rig's centre (its speakers' centroid) was at every located pose."""
    centres = m.speakers.positions_m.mean(axis=1)
    if len(centres) == 0:
        return []
    distance, azimuth, elevation = _angles(centres)
    return [PoseTaken(step=step, distance_m=float(d), azimuth_deg=float(a),
                      elevation_deg=float(e))
            for step, d, a, e in zip(m.speakers.steps, distance, azimuth, elevation,
                                     strict=True)]


def _board_outline_rig(m: Measurements) -> np.ndarray:
    """The checkerboard's outer corners in the rig frame (4, 3): the inner-corner grid grown by
    one square on every side, in order round the board."""
    board = m.cameras.board
    s = board.square_m
    x1, y1 = board.corners_x * s, board.corners_y * s
    return np.array([[-s, -s, 0.0], [x1, -s, 0.0], [x1, y1, 0.0], [-s, y1, 0.0]])


def _pixels(m: Measurements, points_cam0: np.ndarray) -> list[tuple[float, float]]:
    """Points (n, 3) of the camera-0 frame projected into camera 0's image, pixels."""
    camera = m.cameras.intrinsics[m.cameras.reference_camera]
    px, _ = cv2.projectPoints(np.ascontiguousarray(points_cam0, dtype=np.float64),
                              np.zeros(3), np.zeros(3), camera.K, camera.dist)
    return [(float(u), float(v)) for u, v in px.reshape(-1, 2)]


def _best_pose(m: Measurements,
               predicted: Callable[[np.ndarray], float]) -> PoseSuggestion | None:
    """The grid position whose rig speakers lower `predicted` most (see module docstring)."""
    centres = m.speakers.positions_m.mean(axis=1)
    if len(centres) == 0:
        return None
    used = np.linalg.norm(centres, axis=1)
    distances = np.unique(np.round([used.min() * 0.9, np.median(used), used.max() * 1.1], 2))
    centroid = m.data.speakers_rig_m.mean(axis=0)
    rig = m.data.speakers_rig_m - centroid
    outline = _board_outline_rig(m) - centroid
    camera = m.cameras.intrinsics[m.cameras.reference_camera]
    best: PoseSuggestion | None = None
    for az in AZIMUTHS_DEG:
        for el in ELEVATIONS_DEG:
            a, e = np.radians(az), np.radians(el)
            direction = np.array([np.sin(a) * np.cos(e), -np.sin(e), np.cos(a) * np.cos(e)])
            # Rig facing the camera: its normal along -direction (any roll will do here).
            facing = Rotation.align_vectors([-direction], [[0.0, 0.0, 1.0]])[0].as_matrix()
            for d in distances:
                rig_to_cam0 = RigidTransform(facing, d * direction)  # rig centroid at d
                speakers = rig_to_cam0.apply(rig)
                board = _pixels(m, rig_to_cam0.apply(outline))
                if not all(0 <= u <= camera.width and 0 <= v <= camera.height
                           for u, v in board):
                    continue  # the board would leave camera 0's view
                value = predicted(speakers)
                if best is None or value < best.predicted_accuracy_m:
                    best = PoseSuggestion(
                        distance_m=float(d), direction=_vec(direction), azimuth_deg=az,
                        elevation_deg=el, predicted_accuracy_m=value, outline_px=board,
                        speakers_px=_pixels(m, speakers))
    return best


def _vec(v: np.ndarray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))
