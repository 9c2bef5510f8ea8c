"""A camera calibration known from elsewhere, read from the files people have.

Accepted: OpenCV's FileStorage YAML, JSON or XML as its calibration sample and most tools
write it (`camera_matrix` or `K`, `distortion_coefficients` or `D`, optionally `image_width`,
`image_height`), the ROS camera_info YAML (the same keys, each a table with `data`), and a
micam result.json (the camera of that name). micam's lens model has OpenCV's first five
coefficients (k1, k2, p1, p2, k3); a file with more non-zero ones (the rational or thin-prism
model) describes another lens model and is refused rather than cut.

The file is untrusted input: its size is bounded before it is read (it is read once, and
OpenCV parses the text from memory), and whatever its parsers make of damaged content ends in
an `IntrinsicsFileError` naming the file, never in one of their own exceptions.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from acquisition.contracts.bounded_files import UnreadableFile, read_bounded_text
from acquisition.contracts.errors import UserError
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
        text = read_bounded_text(path, MAX_FILE_BYTES)
    except UnreadableFile as exc:
        raise IntrinsicsFileError(f"cannot read the intrinsics file: {exc}") from None
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
    except (json.JSONDecodeError, RecursionError):
        return None
    if not (isinstance(doc, dict) and isinstance(doc.get("cameras"), list)):
        return None
    for entry in doc["cameras"]:
        if isinstance(entry, dict) and entry.get("name") == camera:
            try:
                K = np.array(entry["K"], dtype=float).reshape(3, 3)
                dist = np.array(entry["dist"], dtype=float).ravel()
                size = (int(entry["width"]), int(entry["height"]))
                std = entry.get("intrinsics_std")
                std = None if std is None else tuple(float(s) for s in std)
            except (KeyError, TypeError, ValueError, OverflowError) as exc:
                raise IntrinsicsFileError(f"{path}: camera {camera} lacks {exc} or holds "
                                          "something other than numbers there") from None
            return K, dist, size, std
    names = [e.get("name") for e in doc["cameras"] if isinstance(e, dict)]
    raise IntrinsicsFileError(f"{path} is a micam result without camera {camera!r} (it has "
                              f"{names}); name the camera as in that calibration")


def _from_opencv_text(text: str, path: Path) -> tuple:
    """(K, dist, size or None, None) from the text of an OpenCV FileStorage or ROS
    camera_info file."""
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # OpenCV's parse errors surface as either
        raise IntrinsicsFileError(f"{path} is not an OpenCV YAML, JSON or XML file: "
                                  f"{_last_line(exc)}") from None
    try:
        K = _first_values(storage, _MATRIX_KEYS)
        dist = _first_values(storage, _DISTORTION_KEYS)
        width, height = (storage.getNode(k) for k in ("image_width", "image_height"))
        size = (None if width.empty() or height.empty()
                else (int(width.real()), int(height.real())))
    except (cv2.error, SystemError, ValueError, OverflowError) as exc:
        raise IntrinsicsFileError(f"{path}: its calibration cannot be read: "
                                  f"{_last_line(exc)}") from None
    finally:
        storage.release()
    if K is None or K.size != 9:
        raise IntrinsicsFileError(f"{path} has no 3 x 3 camera matrix under any of "
                                  f"{', '.join(_MATRIX_KEYS)}")
    return K.reshape(3, 3), np.zeros(5) if dist is None else dist, size, None


def _last_line(exc: BaseException) -> str:
    """OpenCV's own words (a SystemError wraps the cv2.error that says them), on one line."""
    cause = exc.__cause__ or exc.__context__
    text = str(cause if isinstance(exc, SystemError) and cause is not None else exc)
    lines = text.strip().splitlines()
    return lines[-1].split(" error: ", 1)[-1] if lines else type(exc).__name__


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
