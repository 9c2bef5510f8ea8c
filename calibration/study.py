"""How accuracy grows with the number of sources: the paper's Table II, on simulated sessions.

For a measured session and its truth, `source_count_study` solves for the microphones from
random subsets of N sources (one pose with N speakers for N <= 6, else N / 6 whole poses) and
reports the mean microphone error against the truth beside the Cramer-Rao bound for the same
sources, timing noise and camera pose covariances (`calibration.solve.crlb.joint_crlb`).

Below `PER_BOARD_FROM_SOURCES` (a single pose with fewer than six speakers) the estimator is
the paper's model, c fixed and no latency: there are too few equations per microphone for the
board latencies. From there on the latencies are fitted per board: on a 20-pose sphere session
that halves the error at every N from 6 to 96 (0.25-0.3 mm against 0.44-0.49 mm without).

Two estimators are measured. The camera-frozen solver: beyond about 1 m its error stops
falling with N, because the camera's focal-length error, frozen into every speaker's depth,
dominates (about 2 mm at 1.0-1.5 m with 30 poses), and a single pose can look better than two
because its latencies absorb that pose's depth error. And, from `JOINT_FROM_SOURCES` on, the
joint optical-acoustic fit (`calibration.pipeline.fit_joint`) of the same subset of sources,
with every board view of the session constraining the cameras (as in a calibration, whose
camera images all count): it removes that error. The bound is the camera-frozen model's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

from .solve.crlb import expected_error_norm, joint_crlb
from .errors import CalibrationInputError
from .pipeline import (
    CalibrationOptions,
    Measurements,
    _rig_sources,
    fit_joint,
    solve,
)
from .plan import board_indices
from .solve.solver import MicrophoneSolution

PER_BOARD_FROM_SOURCES = 6
JOINT_FROM_SOURCES = 12
"""Sources (two poses) from which the joint fit is run on each subset too."""
PAPER_TABLE_II_MM = (10.0, 5.5, 5.0, 4.5)
"""The mean-error thresholds of the paper's Table II, millimetres."""
PAPER_TABLE_II_SOURCES = {
    (0.2, 0.6): (3, 7, 23, 51),
    (0.6, 1.0): (3, 6, 18, 35),
    (1.0, 1.4): (3, 4, 35, 71),
    (1.4, 1.8): (3, 24, 25, 27),
    (1.8, 2.2): (4, 36, None, None),
}
"""The paper's Table II: by distance range (m), the sources needed for a mean error below each
of `PAPER_TABLE_II_MM` (None: not reached)."""


@dataclass(frozen=True)
class StudyRow:
    """Mean microphone error for one number of sources.

    Attributes:
        n_sources: sources per trial.
        trials: random subsets solved.
        mean_error_m: mean over trials of the mean microphone error against the truth.
        sem_m: standard error of that mean over trials.
        crlb_m: mean over trials of the bound's mean expected error, E|e| per microphone.
        efficiency: mean_error_m / crlb_m (1 is the best any unbiased estimator can do).
        latency: the latency model of the estimator.
        joint_error_m: the same mean for the joint fit of the same subsets (None below
            `JOINT_FROM_SOURCES`).
        joint_sem_m: its standard error over trials.
    """

    n_sources: int
    trials: int
    mean_error_m: float
    sem_m: float
    crlb_m: float
    efficiency: float
    latency: str
    joint_error_m: float | None = None
    joint_sem_m: float | None = None

    def to_json(self) -> dict:
        return asdict(self)


def _subset(n_sources: int, n_poses: int, n_speakers: int,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(poses, speakers) indices of a random subset of n_sources sources."""
    if n_sources <= n_speakers:
        return rng.choice(n_poses, 1), np.sort(rng.choice(n_speakers, n_sources, replace=False))
    if n_sources % n_speakers:
        raise CalibrationInputError(f"{n_sources} sources: above {n_speakers}, use whole poses "
                                    f"(multiples of {n_speakers})")
    k = n_sources // n_speakers
    if k > n_poses:
        raise CalibrationInputError(
            f"{n_sources} sources need {k} poses; the session has {n_poses}")
    return np.sort(rng.choice(n_poses, k, replace=False)), np.arange(n_speakers)


def source_count_study(m: Measurements, truth: dict, n_sources: Sequence[int], trials: int,
                       seed: int = 0) -> list[StudyRow]:
    """Mean microphone error and its bound for every N in `n_sources` (see module doc)."""
    rng = np.random.default_rng(seed)
    true = {mic["id"]: mic["position_m"] for mic in truth["microphones"]}
    mics_true = np.array([true[int(i)] for i in m.data.mic_ids])
    c = truth["speed_of_sound_m_s"]
    _, board_of_mic = board_indices(m.data)
    n_mic = len(m.data.mic_ids)
    rows = []
    for n in n_sources:
        latency: Literal["per_board", "none"] = (
            "per_board" if n >= PER_BOARD_FROM_SOURCES else "none")
        options = CalibrationOptions(latency=latency)
        errors, bounds, joint = [], [], []
        for _ in range(trials):
            poses, speakers = _subset(n, len(m.located), m.data.n_speakers, rng)
            sol = solve(m, options, poses, speakers)
            errors.append(float(np.mean(np.linalg.norm(sol.positions_m - mics_true, axis=1))))
            if n >= JOINT_FROM_SOURCES:
                joint.append(_joint_error(m, sol, options, poses, speakers, mics_true))
            sigma = m.tofs.std_s[np.asarray(m.located)[poses]][:, speakers].reshape(-1, n_mic)
            bound = joint_crlb(mics_true, _rig_sources(m.data, m.speakers, poses, speakers), c,
                               sigma, fit_speed_of_sound=False, latency=latency,
                               board_of_mic=board_of_mic, reference_board=None,
                               pose_errors=True)
            bounds.append(float(np.mean(expected_error_norm(bound.mic_covariance_m2))))
        mean, crlb = float(np.mean(errors)), float(np.mean(bounds))
        rows.append(StudyRow(n, trials, mean, float(np.std(errors) / np.sqrt(trials)), crlb,
                             mean / crlb, latency,
                             float(np.mean(joint)) if joint else None,
                             float(np.std(joint) / np.sqrt(trials)) if joint else None))
    return rows


def _joint_error(m: Measurements, frozen: MicrophoneSolution, options: CalibrationOptions,
                 poses: np.ndarray, speakers: np.ndarray, mics_true: np.ndarray) -> float:
    """Mean microphone error of the joint fit of one subset (the microphones it placed)."""
    bundle = fit_joint(m, frozen, options, poses, speakers)
    solved = np.flatnonzero(np.all(np.isfinite(frozen.positions_m), axis=1))
    return float(np.mean(np.linalg.norm(bundle.state.microphones_m - mics_true[solved],
                                        axis=1)))


def sources_needed(rows: Sequence[StudyRow], thresholds_mm: Sequence[float] = PAPER_TABLE_II_MM
                   ) -> dict[float, int | None]:
    """The fewest sources whose mean camera-frozen error is below each threshold (None if
    none is)."""
    return {t: min((r.n_sources for r in rows if r.mean_error_m * 1e3 < t), default=None)
            for t in thresholds_mm}
