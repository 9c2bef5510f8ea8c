"""Geometry of the simulated world: cameras, the calibration rig and rig poses.

Frames (all right-handed, metres):
- camera frames follow OpenCV: x right, y down, z forward along the optical axis;
- the *world* frame of the simulation is the frame of camera 0; every position in truth.json
  is expressed in it;
- the *rig* frame is the paper's checkerboard frame (Table I): origin at an extreme inner corner
  of the checkerboard, X along the 6-corner side, Y along the 9-corner side, Z out of the printed
  face (towards a camera that sees the board). The speakers sit 2.5 mm behind the face
  (Z = -2.5 mm).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np

from kernel.rigid import RigidTransform, rotation_from_rotvec, rotvec_from_rotation

__all__ = ["CameraModel", "Rig", "RigidTransform", "pinhole", "rotation_from_rotvec",
           "rotvec_from_rotation"]


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera with OpenCV's 5-coefficient distortion (the paper's equation 4).

    Attributes:
        name: "cam0", "cam1", ...
        width, height: image size in pixels.
        K: 3x3 intrinsic matrix (focal lengths and principal point in pixels).
        dist: distortion coefficients (k1, k2, p1, p2, k3), OpenCV order.
        cam0_to_cam: the transform from the camera-0 frame into this camera's frame.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    cam0_to_cam: RigidTransform = field(default_factory=RigidTransform.identity)

    def project(self, points_cam0: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of points (N, 3) given in the camera-0 frame."""
        pts = self.cam0_to_cam.apply(np.asarray(points_cam0, dtype=np.float64).reshape(-1, 3))
        px, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.dist)
        return px.reshape(-1, 2)

    def in_front(self, points_cam0: np.ndarray) -> np.ndarray:
        """Boolean mask of points that lie in front of the camera (positive depth)."""
        pts = self.cam0_to_cam.apply(np.asarray(points_cam0, dtype=np.float64).reshape(-1, 3))
        return pts[:, 2] > 1e-3

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "from_cam0": self.cam0_to_cam.to_json(),
        }


def pinhole(
    name: str,
    width: int = 1280,
    height: int = 960,
    focal_px: float = 1000.0,
    dist: tuple[float, float, float, float, float] = (-0.08, 0.05, 0.0005, -0.0003, 0.0),
    cam0_to_cam: RigidTransform | None = None,
) -> CameraModel:
    """A camera with square pixels, its principal point near the image centre."""
    K = np.array(
        [[focal_px, 0.0, width / 2 + 3.5], [0.0, focal_px, height / 2 - 2.5], [0.0, 0.0, 1.0]]
    )
    return CameraModel(
        name=name,
        width=width,
        height=height,
        K=K,
        dist=np.array(dist, dtype=np.float64),
        cam0_to_cam=cam0_to_cam or RigidTransform.identity(),
    )


# The paper's Table I, in millimetres, rig frame.
PAPER_SPEAKERS_MM = np.array(
    [
        [-60.0, 0.0, -2.5],
        [210.0, 0.0, -2.5],
        [-60.0, 240.0, -2.5],
        [210.0, 240.0, -2.5],
        [-60.0, 120.0, -2.5],
        [210.0, 120.0, -2.5],
    ]
)


@dataclass(frozen=True)
class Rig:
    """The calibration rig: a plate with a printed checkerboard and speakers around it.

    Attributes:
        corners_x, corners_y: inner corners of the checkerboard along the rig's X and Y axes
            (6 x 9 with 30 mm squares puts the paper's speakers two squares beside the pattern,
            at corner rows).
        square_m: side of one checkerboard square.
        speakers_m: (n_speakers, 3) speaker acoustic centres in the rig frame.
        speaker_diameter_m: drawn in the images as discs.
        plate_m: (x_min, x_max, y_min, y_max) of the white plate in the rig frame.
        reference_mark_m: the rig point placed at the reference microphone for the
            reference-microphone image (paper IV-C): here the plate's corner.
        origin_square: colour of the printed square between the origin corner and its
            neighbours along +X and +Y ("dark", micam's own print, or "light", the opposite
            convention; see sim.light).
        sag_m: the plate's bow (sim.optics' board-bow): the printed face is the paraboloid
            Z = sag_m (1 - rho^2 / rho_c^2), rho the distance from the plate's centre and
            rho_c the plate's half-diagonal (the plate's corners stay at Z = 0; its centre
            is sag_m out of the printed face, towards the camera for sag_m > 0). 0: flat.
    """

    corners_x: int = 6
    corners_y: int = 9
    square_m: float = 0.030
    speakers_m: np.ndarray = field(default_factory=lambda: PAPER_SPEAKERS_MM / 1000.0)
    speaker_diameter_m: float = 0.026
    plate_m: tuple[float, float, float, float] = (-0.090, 0.240, -0.060, 0.300)
    reference_mark_m: np.ndarray = field(default_factory=lambda: np.array([-0.090, -0.060, 0.0]))
    origin_square: Literal["dark", "light"] = "dark"
    sag_m: float = 0.0

    @property
    def n_speakers(self) -> int:
        return int(self.speakers_m.shape[0])

    def bow_height_m(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Z of the bowed face (see `sag_m`) at rig coordinates (X, Y), metres."""
        x0, x1, y0, y1 = self.plate_m
        dx, dy = X - np.float32((x0 + x1) / 2), Y - np.float32((y0 + y1) / 2)
        rho_c2 = np.float32(((x1 - x0) / 2) ** 2 + ((y1 - y0) / 2) ** 2)
        return np.float32(self.sag_m) * (1.0 - (dx * dx + dy * dy) / rho_c2)

    def corner_points(self) -> np.ndarray:
        """Inner corners (corners_x * corners_y, 3) in the rig frame, X varying fastest (on
        the bowed face: Z = 0 for a flat plate)."""
        ix, iy = np.meshgrid(np.arange(self.corners_x), np.arange(self.corners_y))
        X, Y = ix.ravel() * self.square_m, iy.ravel() * self.square_m
        return np.stack([X, Y, self.bow_height_m(X, Y).astype(np.float64)], axis=1)

    def turned(self) -> Rig:
        """The rig described from the pattern's opposite inner corner: its speakers turned by
        180 degrees in the board plane about the pattern's centre (a half-turn, so the
        frame stays right-handed with Z out of the face)."""
        speakers = self.speakers_m.copy()
        speakers[:, :2] = 2 * self.centre()[:2] - speakers[:, :2]
        return replace(self, speakers_m=speakers)

    def centre(self) -> np.ndarray:
        """Centre of the checkerboard pattern in the rig frame."""
        return np.array(
            [(self.corners_x - 1) * self.square_m / 2, (self.corners_y - 1) * self.square_m / 2, 0]
        )

    def to_json(self) -> dict:
        return {
            "corners_x": self.corners_x,
            "corners_y": self.corners_y,
            "square_m": self.square_m,
            "speakers_m": self.speakers_m.tolist(),
            "speaker_diameter_m": self.speaker_diameter_m,
            "plate_m": list(self.plate_m),
            "reference_mark_m": self.reference_mark_m.tolist(),
            "origin_square": self.origin_square,
        }
