"""The one implementation of each job: rigid transforms, robust fitting helpers, atomic writes,
and the rules the test suite keeps (no fork of the threaded pytest process)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from acquisition.contracts.session import partial_path, sha256_file, write_atomic
from calibration.solve.robust import inverse_normal, robust_sigma
from kernel.rigid import (
    RigidTransform,
    kabsch,
    rotated_point_jacobian,
    rotation_from_rotvec,
    rotvec_from_rotation,
)

REPO = Path(__file__).resolve().parents[1]


def test_rotations_round_trip_and_stay_exact_near_a_half_turn() -> None:
    rng = np.random.default_rng(0)
    v = rng.normal(size=(20, 3))
    unit = v / np.linalg.norm(v, axis=1)[:, None]  # angles of 1 rad: below pi, no wrap
    assert np.allclose(rotvec_from_rotation(rotation_from_rotvec(unit)), unit, atol=1e-12)
    near_pi = np.array([0.0, 0.0, np.pi - 1e-7])
    R = rotation_from_rotvec(near_pi)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-15)
    assert np.allclose(rotvec_from_rotation(R), near_pi, atol=1e-9)
    assert np.allclose(R, cv2.Rodrigues(near_pi)[0], atol=1e-6)  # OpenCV's convention


def test_a_transform_composes_inverts_and_is_found_by_kabsch() -> None:
    rng = np.random.default_rng(1)
    T = RigidTransform.from_rotvec(np.array([0.3, -0.2, 0.5]), np.array([0.1, 0.2, 0.9]))
    points = rng.normal(size=(12, 3))
    assert np.allclose(T.inverse().apply(T.apply(points)), points)
    assert np.allclose(T.compose(T.inverse()).apply(points), points)
    found = kabsch(points, T.apply(points))
    assert np.allclose(found.R, T.R) and np.allclose(found.t, T.t)
    moved = T.apply(points)
    assert np.allclose(T.inverse_apply(moved), points, atol=1e-15)
    assert np.array_equal(T.inverse_apply(moved), (moved - T.t) @ T.R)
    other = RigidTransform.from_rotvec(np.array([-0.1, 0.4, 0.2]), np.array([0.3, 0.0, -0.2]))
    both = T.inverse_compose(other)
    assert np.allclose(both.R, T.inverse().compose(other).R, atol=1e-15)
    assert np.allclose(both.apply(points), T.inverse_apply(other.apply(points)), atol=1e-15)


def test_a_transform_keeps_the_rotation_vector_it_was_made_from() -> None:
    """Near a half turn r and r (1 - 2 pi / |r|) are one rotation; the fitted one comes back,
    bit for bit, so a covariance of (rotvec, t) stays the covariance of `params`."""
    beyond = np.array([0.0, 0.0, np.pi + 1e-3])  # a fit may step past a half turn
    T = RigidTransform.from_rotvec(beyond, np.array([0.1, 0.2, 0.9]))
    assert np.array_equal(T.rotvec, beyond)
    assert np.array_equal(T.params, [0.0, 0.0, np.pi + 1e-3, 0.1, 0.2, 0.9])
    from_matrix = RigidTransform(T.R, T.t).rotvec  # angle in [0, pi]: the other branch
    assert np.linalg.norm(from_matrix) < np.pi
    assert np.allclose(rotation_from_rotvec(from_matrix), T.R, atol=1e-15)
    assert T.compose(RigidTransform.identity()).rotvec[2] < 0  # a new transform: R's vector


ROTATION_FIELDS = {"R", "rotation", "rotation_matrix", "rvec", "rotvec"}
TRANSLATION_FIELDS = {"t", "tvec", "t_m", "translation", "translation_m"}
NOT_A_TRANSFORM_TYPE = {
    ("kernel/rigid.py", "RigidTransform"): "the one type",
    ("calibration/result.py", "TransformResult"): "result.json's form of one (the schema)",
    ("calibration/solve/solver.py", "RigSources"): "the solver's batched (n_pose, 3) unknowns",
}


def transform_like_classes(source: str) -> list[str]:
    """Classes of `source` with both a rotation field and a translation field among their
    annotated class attributes (dataclasses, NamedTuples, pydantic models)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ClassDef):
            fields = {s.target.id for s in node.body
                      if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)}
            if fields & ROTATION_FIELDS and fields & TRANSLATION_FIELDS:
                found.append(node.name)
    return found


def test_a_record_with_its_own_rotation_and_translation_is_found() -> None:
    assert transform_like_classes(
        "@dataclass\nclass Pose:\n    rvec: np.ndarray\n    tvec: np.ndarray\n"
        "class Ok:\n    rig_to_cam: RigidTransform\n    t: float\n") == ["Pose"]


@pytest.mark.slow
def test_no_type_but_rigid_transform_holds_a_rotation_and_a_translation() -> None:
    """#18 found five types for one rigid transform; records hold a RigidTransform in a field
    named for its direction (`cam0_to_cam`, `rig_to_cam0`) instead of their own R and t."""
    found = {(str(path.relative_to(REPO)), name)
             for top in ("acquisition", "calibration", "daq", "imaging", "kernel", "micam", "sim",
                         "benchmarks", "tests")
             for path in sorted((REPO / top).rglob("*.py"))
             for name in transform_like_classes(path.read_text())}
    assert found - NOT_A_TRANSFORM_TYPE.keys() == set()
    assert NOT_A_TRANSFORM_TYPE.keys() <= found  # the exceptions still exist as named


def test_the_rotation_jacobian_matches_finite_differences() -> None:
    rotvec, point = np.array([[0.4, -0.1, 0.7]]), np.array([[0.2, 0.3, -0.5]])
    analytic = rotated_point_jacobian(rotvec, point)[0]
    step = 1e-7
    numeric = np.stack([(rotation_from_rotvec(rotvec[0] + step * e) @ point[0]
                         - rotation_from_rotvec(rotvec[0] - step * e) @ point[0]) / (2 * step)
                        for e in np.eye(3)], axis=1)
    assert np.allclose(analytic, numeric, atol=1e-7)


def test_robust_sigma_ignores_outliers_and_keeps_its_floor() -> None:
    rng = np.random.default_rng(2)
    r = np.concatenate([rng.normal(0, 2.0, 10_000), np.full(500, 1e3)])
    assert robust_sigma(r) == pytest.approx(2.0, rel=0.1)  # 5 % outliers move it 6 %
    assert np.std(r) > 100
    assert robust_sigma(np.zeros(5), floor=1e-6) == 1e-6
    with pytest.raises(ValueError, match="at least one residual"):
        robust_sigma(np.array([]))


def test_inverse_normal_inverts_badly_scaled_and_singular_matrices() -> None:
    J = np.array([[1e3, 0.0, 1.0], [0.0, 1e-3, 1.0], [1.0, 1.0, 1.0], [2.0, 0.5, 0.1]])
    A = J.T @ J
    assert np.allclose(inverse_normal(A) @ A, np.eye(3), atol=1e-8)
    singular = np.array([[1.0, 1.0], [1.0, 1.0]])
    assert np.allclose(inverse_normal(singular), np.linalg.pinv(singular))


def test_an_atomic_replace_drops_a_stale_partial_and_a_failed_one_leaves_none(
        tmp_path: Path) -> None:
    path = tmp_path / "result.json"
    partial_path(path).write_bytes(b"left by a crash")
    digest = write_atomic(path, lambda fh: fh.write(b"{}"), replace=True)
    assert path.read_bytes() == b"{}" and not partial_path(path).exists()
    assert digest == sha256_file(path)

    def fail(_fh: object) -> None:
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(path, fail, replace=True)
    assert path.read_bytes() == b"{}" and not partial_path(path).exists()


def test_no_test_forks_the_test_process() -> None:
    """os.fork() of pytest copies its threads' locks mid-use; children come from a fork
    server or a subprocess instead."""
    offenders = [str(p.relative_to(REPO)) for p in (REPO / "tests").rglob("*.py")
                 if re.search(r"\bos\.fork\(", p.read_text()) and p.name != Path(__file__).name]
    assert offenders == []


def test_one_chessboard_detector() -> None:
    """#29 found two (the daemon's quality check and the calibration's quick path, with other
    flags and scales): OpenCV's classic detector and its fast check are called in
    kernel.chessboard alone (the calibration's sector-based fallback is another detector)."""
    calls = re.compile(r"\b(findChessboardCorners|checkChessboard)\(")
    found = sorted(str(path.relative_to(REPO))
                   for top in ("acquisition", "calibration", "daq", "imaging", "kernel", "micam",
                               "sim")
                   for path in (REPO / top).rglob("*.py") if calls.search(path.read_text()))
    assert found == ["kernel/chessboard.py"]


@pytest.mark.slow
def test_the_daemon_sees_the_corners_the_calibration_starts_from() -> None:
    """A pose the daemon's quick look accepts is one the calibration's quick path finds, at
    the corners the daemon drew (unrefined, within a pixel of the refined ones)."""
    from acquisition.daemon.quality import checkerboard_corners
    from calibration.camera.corners import Checkerboard, detect_corners_quickly
    from sim.capture import SimulationOptions, build_simulated_capture

    sim = build_simulated_capture(SimulationOptions(array="scatter48", poses=1, seed=3))
    sim.world.place_rig(sim.poses[0])
    image = sim.cameras[0].grab().image
    board = Checkerboard.of_rig(sim.config.rig)
    daemon = checkerboard_corners(image, board.pattern_size)
    calibration = detect_corners_quickly(image, board)
    assert daemon is not None and isinstance(calibration, np.ndarray)
    assert daemon.shape == calibration.shape
    nearest = np.linalg.norm(calibration[:, None, :] - daemon[None, :, :], axis=2).min(axis=1)
    assert nearest.max() < 1.0, nearest.max()
