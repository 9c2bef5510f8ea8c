"""What imaging needs to know about an array: microphones, speed of sound, cameras, rig poses.

Read from a calibration result (result.json) or a simulation's ground truth (truth.json); both
have the same keys:

    {"microphones": [{"id": int, "position_m": [x, y, z]}, ...],
     "speed_of_sound_m_s": float,
     "cameras": [{"name", "width", "height", "K": 3x3, "dist": [k1, k2, p1, p2, k3],
                  "from_cam0": {"rotvec": [3], "t_m": [3]}}, ...],
     "poses": [{"index": int, "rig_to_cam0": {"rotvec", "t_m"}, "speakers_m": [[x, y, z]...]}]}

Positions are metres in the camera-0 frame (OpenCV: x right, y down, z forward); "poses" is
optional (needed for scanning the rig plane and for evaluation). When the document also has
"board_latencies_s" (truth.json) or "latency_s" (result.json), {serial: seconds}, and each
microphone its "board", the latencies are
applied per microphone (`ArrayGeometry.mic_latencies_s`); otherwise they are taken as 0. A
microphone's own "delay_s" (result.json: its capsule's and channel's delay beyond its board's
latency, when the joint fit estimated it) is added to its latency.
An optional "microphone_responses" (result.json: each channel's gain and phase against
frequency, see `csm_calibration`) is read into `ArrayGeometry.responses`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from acquisition.contracts.bounded_files import (
    MAX_DOCUMENT_BYTES,
    UnreadableFile,
    read_bounded_text,
)
from calibration.errors import CalibrationInputError
from kernel.rigid import RigidTransform

from .csm_calibration import ChannelResponses, responses_from_document

MAX_LATENCY_S = 0.01
"""Largest channel latency or delay a geometry file may state (a board's is microseconds)."""


class GeometryFileError(CalibrationInputError):
    """A geometry document cannot be read or is not one; the message names the file and what
    is wrong."""


@dataclass(frozen=True)
class CameraView:
    """A calibrated camera: `cam0_to_cam` (x_cam = R x_cam0 + t, metres), then OpenCV's
    pinhole (K, pixels) and distortion (k1, k2, p1, p2, k3)."""

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    cam0_to_cam: RigidTransform

    def to_camera(self, points_cam0: np.ndarray) -> np.ndarray:
        """Points (N, 3) of the camera-0 frame in this camera's frame."""
        return self.cam0_to_cam.apply(np.asarray(points_cam0, dtype=np.float64).reshape(-1, 3))

    def project(self, points_cam0: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of points (N, 3) of the camera-0 frame, with distortion."""
        pts = self.to_camera(points_cam0)
        px, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.dist)
        return px.reshape(-1, 2)

    def sees(self, points_cam0: np.ndarray) -> np.ndarray:
        """Whether each point (N, 3) of the camera-0 frame is in this camera's image: in front
        of it and projected within its width and height (pixels)."""
        in_front = self.to_camera(points_cam0)[:, 2] > 0
        px = self.project(points_cam0)
        inside = ((px >= 0) & (px < np.array([self.width, self.height]))).all(axis=1)
        return np.asarray(in_front & inside)


@dataclass(frozen=True)
class BoardPose:
    """A rig pose: `rig_to_cam0` (x_cam0 = R x_rig + t, metres), and the speakers'
    positions (n, 3) in camera 0, metres."""

    index: int
    rig_to_cam0: RigidTransform
    speakers_m: np.ndarray


@dataclass(frozen=True)
class ArrayGeometry:
    """Microphone ids, positions (M, 3) and channel latencies (M,), c, cameras, rig poses,
    and the channels' complex responses when the calibration measured them.

    mic_latencies_s is each channel's board latency plus its microphone's own delay
    (mic_own_delays_s, zeros when the document has none)."""

    mic_ids: tuple[int, ...]
    mic_positions_m: np.ndarray
    speed_of_sound_m_s: float
    cameras: tuple[CameraView, ...]
    poses: dict[int, BoardPose]
    mic_latencies_s: np.ndarray
    responses: ChannelResponses | None = None
    mic_own_delays_s: np.ndarray | None = None

    @property
    def n_mics(self) -> int:
        return len(self.mic_ids)

    @property
    def centre_m(self) -> np.ndarray:
        """The centroid of the microphones (the array's centre of projection, paper VI-B)."""
        return self.mic_positions_m.mean(axis=0)

    def without_own_delays(self) -> ArrayGeometry:
        """The geometry with the board latencies only: for a CSM corrected by responses that
        already hold each microphone's own delay (result.json's microphone_responses)."""
        if self.mic_own_delays_s is None:
            return self
        return replace(self, mic_latencies_s=self.mic_latencies_s - self.mic_own_delays_s,
                       mic_own_delays_s=None)

    def camera(self, name: str) -> CameraView:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise CalibrationInputError(f"no camera {name!r} in the geometry; it has "
                                    f"{', '.join(c.name for c in self.cameras) or 'none'}")

    def pose(self, index: int) -> BoardPose:
        if index not in self.poses:
            raise CalibrationInputError(
                f"the geometry has no rig pose {index}; it has {sorted(self.poses) or 'none'} "
                "(a calibration result.json or a truth.json with \"poses\" is needed)")
        return self.poses[index]


def geometry_from_dict(doc: dict, source: str = "geometry") -> ArrayGeometry:
    """Parse a result.json / truth.json document (see the module docstring)."""
    try:
        mics = sorted(doc["microphones"], key=lambda m: int(m["id"]))
        ids = tuple(int(m["id"]) for m in mics)
        positions = np.array([m["position_m"] for m in mics], dtype=np.float64)
        c = float(doc["speed_of_sound_m_s"])
        cameras = tuple(
            CameraView(name=str(cam["name"]), width=int(cam["width"]), height=int(cam["height"]),
                       K=np.array(cam["K"], dtype=np.float64),
                       dist=np.array(cam["dist"], dtype=np.float64),
                       cam0_to_cam=_transform(cam["from_cam0"]))
            for cam in doc.get("cameras", []))
        poses = {
            int(p["index"]): BoardPose(int(p["index"]), _transform(p["rig_to_cam0"]),
                                       np.array(p["speakers_m"], dtype=np.float64))
            for p in doc.get("poses", [])}
        # truth.json: "board_latencies_s" (absolute); result.json: "latency_s" (relative to the
        # reference microphone's board). Only differences between channels matter for imaging.
        by_board = doc.get("board_latencies_s", doc.get("latency_s", {}))
        board_latency = {str(k): float(v) for k, v in by_board.items()}
        own = np.array([float(m.get("delay_s") or 0.0) for m in mics])
        latencies = np.array([board_latency.get(str(m.get("board")), 0.0) for m in mics]) + own
    except (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError) as exc:
        raise GeometryFileError(f"{source}: not a calibration result or truth document "
                                f"({exc!r}); it needs microphones[].id/position_m, "
                                "speed_of_sound_m_s and cameras[]") from None
    if (positions.ndim != 2 or positions.shape[1] != 3 or len(set(ids)) != len(ids)
            or not np.all(np.isfinite(positions))):
        raise GeometryFileError(f"{source}: microphone positions must be (M, 3) finite numbers "
                                "with unique ids")
    if not 0 < c < np.inf:
        raise GeometryFileError(f"{source}: speed of sound {c} m/s must be positive and finite")
    if not np.all(np.abs(latencies) < MAX_LATENCY_S):
        raise GeometryFileError(f"{source}: channel latencies and delays must be finite and "
                                f"below {1e3 * MAX_LATENCY_S:g} ms")
    for cam in cameras:
        if (cam.K.shape != (3, 3) or cam.dist.ndim != 1 or not 4 <= cam.dist.size <= 14
                or not (np.all(np.isfinite(cam.K)) and np.all(np.isfinite(cam.dist)))
                or not (0 < cam.width <= 100_000 and 0 < cam.height <= 100_000)):
            raise GeometryFileError(f"{source}: camera {cam.name!r} needs a finite 3 x 3 K, "
                                    "4 to 14 finite distortion coefficients and a size in "
                                    "pixels")
    for pose in poses.values():
        if (pose.speakers_m.ndim != 2 or pose.speakers_m.shape[1] != 3
                or not np.all(np.isfinite(pose.speakers_m))):
            raise GeometryFileError(f"{source}: pose {pose.index} needs speakers_m as (n, 3) "
                                    "finite numbers")
    return ArrayGeometry(ids, positions, c, cameras, poses, latencies,
                         responses_from_document(doc, ids, source),
                         own if np.any(own) else None)


def _transform(doc: dict) -> RigidTransform:
    """A document's {"rotvec": [3] radians, "t_m": [3] metres}."""
    return RigidTransform.from_rotvec(doc["rotvec"], np.array(doc["t_m"], dtype=np.float64))


def load_geometry(path: Path) -> ArrayGeometry:
    """Read a calibration result.json or a simulation's truth.json (of at most
    MAX_DOCUMENT_BYTES).

    Raises:
        GeometryFileError: unreadable, not JSON, or not a geometry (see `geometry_from_dict`).
    """
    path = Path(path)
    try:
        doc = json.loads(read_bounded_text(path, MAX_DOCUMENT_BYTES))
    except UnreadableFile as exc:
        raise GeometryFileError(f"cannot read the geometry: {exc}") from None
    except (json.JSONDecodeError, RecursionError) as exc:
        raise GeometryFileError(f"cannot read the geometry {path}: it is not JSON "
                                f"({exc})") from None
    return geometry_from_dict(doc, str(path))
