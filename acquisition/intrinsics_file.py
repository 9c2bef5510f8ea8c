"""A camera calibration known from elsewhere, read from the files people have.

Accepted: OpenCV's FileStorage YAML, JSON or XML as its calibration sample and most tools
write it (`camera_matrix` or `K`, `distortion_coefficients` or `D`, optionally `image_width`,
`image_height`), the ROS camera_info YAML (the same keys, each a table with `data`), and a
micam result.json (the camera of that name). micam's lens model has OpenCV's first five
coefficients (k1, k2, p1, p2, k3); a file with more non-zero ones (the rational or thin-prism
model) describes another lens model and is refused rather than cut.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from acquisition.contracts.errors import UserError
from acquisition.contracts.read_once import TooLarge, read_at_most
from acquisition.contracts.rig_description import CAMERA_MODEL_COEFFICIENTS, KnownIntrinsics

MAX_FILE_BYTES = 1_000_000
"""An intrinsics file is a few hundred bytes; anything far larger is not one."""

_MATRIX_KEYS = ("camera_matrix", "cameraMatrix", "K", "intrinsic_matrix")
_DISTORTION_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D")


class IntrinsicsFileError(UserError):
    """The file is not a camera calibration micam can use; the message says why."""


def read_intrinsics(path: Path, camera: str, size: tuple[int, int] | None,
                    use: Literal["prior", "fixed"] = "prior",
                    std: tuple[float, ...] | None = None) -> KnownIntrinsics:
    """The known intrinsics of `camera` from `path`.

    Args:
        path: the file.
        camera: the camera's name (picks the camera of a micam result.json).
        size: the camera's (width, height); a file that states another size is refused.
        use: "prior" or "fixed" (see `KnownIntrinsics`).
        std: standard deviations of fx, fy, cx, cy, k1, k2, p1, p2, k3; by default those of
            a micam result.json, else none (then `use` must be "fixed").

    Raises:
        IntrinsicsFileError: unreadable, not a calibration, another lens model or image size.
    """
    path = Path(path)
    try:
        text = read_at_most(path, MAX_FILE_BYTES).decode("utf-8")  # once: it may be a pipe
    except TooLarge:
        raise IntrinsicsFileError(f"{path} is larger than {MAX_FILE_BYTES} bytes, too large "
                                  "for a camera calibration") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise IntrinsicsFileError(f"cannot read the intrinsics file {path}: {exc}") from None
    found = _from_micam_result(text, camera, path) or _from_opencv_text(text, path)
    K, dist, file_size, file_std = found
    if size is not None and file_size is not None and tuple(file_size) != tuple(size):
        raise IntrinsicsFileError(
            f"{path} calibrates images of {file_size[0]} x {file_size[1]} pixels, camera "
            f"{camera} takes {size[0]} x {size[1]}; use the calibration of this camera at this "
            "resolution")
    std = std if std is not None else file_std
    try:
        return KnownIntrinsics.model_validate({
            "use": use, "camera_matrix": K.tolist(),
            "distortion": _five_coefficients(dist, path).tolist(),
            "std": None if std is None else list(std)})
    except ValueError as exc:
        raise IntrinsicsFileError(f"{path}: {exc}") from None


def _from_micam_result(text: str, camera: str, path: Path) -> tuple | None:
    """(K, dist, size, std) of `camera` in a micam result.json, or None for another file."""
    try:
        doc = json.loads(text)
    except json.JSONDecodeError:
        return None
    if not (isinstance(doc, dict) and isinstance(doc.get("cameras"), list)):
        return None
    for entry in doc["cameras"]:
        if isinstance(entry, dict) and entry.get("name") == camera:
            try:
                K = np.array(entry["K"], dtype=float).reshape(3, 3)
                dist = np.array(entry["dist"], dtype=float).ravel()
                size = (int(entry["width"]), int(entry["height"]))
            except (KeyError, TypeError, ValueError) as exc:
                raise IntrinsicsFileError(f"{path}: camera {camera} lacks {exc}") from None
            std = entry.get("intrinsics_std")
            return K, dist, size, None if std is None else tuple(float(s) for s in std)
    names = [e.get("name") for e in doc["cameras"] if isinstance(e, dict)]
    raise IntrinsicsFileError(f"{path} is a micam result without camera {camera!r} (it has "
                              f"{names}); name the camera as in that calibration")


def _from_opencv_text(text: str, path: Path) -> tuple:
    """(K, dist, size or None, None) from the text of an OpenCV FileStorage or ROS
    camera_info file (`path` names it in errors)."""
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except cv2.error as exc:
        raise IntrinsicsFileError(f"{path} is not an OpenCV YAML, JSON or XML file: "
                                  f"{str(exc).strip().splitlines()[-1]}") from None
    try:
        K = _first_values(storage, _MATRIX_KEYS)
        dist = _first_values(storage, _DISTORTION_KEYS)
        width, height = (storage.getNode(k) for k in ("image_width", "image_height"))
        size = (None if width.empty() or height.empty()
                else (int(width.real()), int(height.real())))
    finally:
        storage.release()
    if K is None or K.size != 9:
        raise IntrinsicsFileError(f"{path} has no 3 x 3 camera matrix under any of "
                                  f"{', '.join(_MATRIX_KEYS)}")
    return K.reshape(3, 3), np.zeros(5) if dist is None else dist, size, None


def _first_values(storage: cv2.FileStorage, keys: tuple[str, ...]) -> np.ndarray | None:
    for key in keys:
        node = storage.getNode(key)
        if not node.empty():
            return _node_values(node)
    return None


def _node_values(node: cv2.FileNode) -> np.ndarray | None:
    """The numbers of an OpenCV matrix node, a ROS `{rows, cols, data}` table or a list."""
    try:
        matrix = node.mat()
        if matrix is not None and matrix.size:
            return matrix.astype(np.float64).ravel()
    except cv2.error:
        pass  # a table without OpenCV's type (ROS): read its data list below
    if node.isMap():
        node = node.getNode("data")
    if node.isSeq():
        return np.array([node.at(i).real() for i in range(node.size())])
    return None


def _five_coefficients(dist: np.ndarray, path: Path) -> np.ndarray:
    """OpenCV's k1, k2, p1, p2, k3 from a file's coefficients (4, 5, 8, 12 or 14 of them)."""
    dist = np.asarray(dist, dtype=float).ravel()
    if dist.size < 4:
        raise IntrinsicsFileError(f"{path}: {dist.size} distortion coefficients; give at "
                                  "least k1, k2, p1, p2")
    extra = dist[CAMERA_MODEL_COEFFICIENTS:]
    if np.any(extra != 0):
        raise IntrinsicsFileError(
            f"{path}: {dist.size} distortion coefficients with non-zero ones beyond k3 (a "
            "rational or thin-prism lens model); micam's model has k1, k2, p1, p2, k3 only, so "
            "recalibrate the camera with those, or let micam calibrate it from the images")
    return np.concatenate([dist, np.zeros(CAMERA_MODEL_COEFFICIENTS)])[:CAMERA_MODEL_COEFFICIENTS]
