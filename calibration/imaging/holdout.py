"""Imaging evaluated on poses the calibration has not seen: k-fold cross-validation over poses.

Scored with a result calibrated from the same session, `evaluate_session` is in-sample: the
microphones were fitted to the times of flight from the very speaker positions the maps are
compared with. Here the located poses are dealt into k folds (the i-th located pose into fold
i mod k). For each fold the microphones, c and the latencies are calibrated from the sources
of the other folds only (`pipeline.calibrate_measured`; every board image still calibrates
the cameras and places its board, as the camera would for any new recording), and the fold's
recordings are imaged with that calibration: held-out. In-sample is the calibration from
every pose imaging every pose. The measurements (corners, times of flight) are made once.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from acquisition.contracts.session import SessionReader
from acquisition.contracts.step_ids import pose_index

from ..errors import CalibrationInputError
from ..pipeline import CalibrationOptions, CalibrationRun, calibrate_measured, measure
from .evaluate import (
    Evaluation,
    ImagingSettings,
    Localization,
    evaluate_session,
    session_recordings,
)
from .geometry import ArrayGeometry, geometry_from_dict

MIN_TRAINING_POSES = 2
"""Poses each fold's calibration needs at least (12 sources: the joint fit's minimum)."""


@dataclass(frozen=True)
class CrossValidation:
    """In-sample and held-out localizations of the same recordings.

    Attributes:
        in_sample: every pose imaged with the calibration from every pose.
        held_out: every pose imaged with the calibration that left its fold out.
        folds: the pose numbers of each fold.
    """

    in_sample: Evaluation
    held_out: Evaluation
    folds: list[list[int]]

    def to_json(self) -> dict:
        return {"folds": self.folds, "in_sample": self.in_sample.to_json(),
                "held_out": self.held_out.to_json()}


def fold_poses(poses: list[int], folds: int) -> list[list[int]]:
    """The poses dealt into `folds` folds, the i-th into fold i mod folds. Raises ValueError
    when a fold would leave fewer than `MIN_TRAINING_POSES` poses to calibrate from."""
    if folds < 2:
        raise CalibrationInputError(f"{folds} folds: cross-validation needs at least 2")
    largest = math.ceil(len(poses) / folds)
    if len(poses) - largest < MIN_TRAINING_POSES or folds > len(poses):
        raise CalibrationInputError(
            f"{len(poses)} located poses cannot be split into {folds} folds that "
            f"each leave {MIN_TRAINING_POSES} poses to calibrate from; use fewer "
            "folds or a longer session")
    return [poses[k::folds] for k in range(folds)]


def geometry_of(run: CalibrationRun) -> ArrayGeometry:
    """The imaging geometry of a calibration, as if read from its result.json."""
    return geometry_from_dict(json.loads(run.result.model_dump_json()), "the calibration")


def cross_validate(session: Path, folds: int, settings: ImagingSettings | None = None,
                   options: CalibrationOptions | None = None, truth: ArrayGeometry | None = None,
                   progress: Callable[[int, int], None] | None = None,
                   workers: int | None = 1) -> CrossValidation:
    """In-sample and k-fold held-out CLEAN-SC localization of a session (module docstring).

    Args:
        options: the calibration's options (default: `micam calibrate`'s).
        truth: a simulated session's truth, to measure errors against it too.
        progress: called with (done, total) recordings over both evaluations.
        workers: processes for the imaging (see `evaluate_session`).
    """
    settings = settings or ImagingSettings()
    options = options or CalibrationOptions()
    reader = SessionReader(session)
    m = measure(session, options)
    numbers = [pose_index(p.step) for p in m.speakers.poses]
    located = [n for n in numbers if n is not None]
    split = fold_poses(located, folds)
    recorded = {pose: len(r) for pose, r in session_recordings(reader).items()}
    total = 2 * sum(recorded.get(pose, 0) for pose in located)
    done = 0

    def evaluate(geometry: ArrayGeometry, poses: list[int]) -> list[Localization]:
        nonlocal done
        offset = done

        def step(count: int, _total: int) -> None:
            if progress is not None:
                progress(offset + count, total)

        rows = evaluate_session(reader, geometry, settings, step, workers, poses=poses,
                                truth=truth).rows
        done = offset + sum(recorded.get(pose, 0) for pose in poses)
        return rows

    in_sample = evaluate(geometry_of(calibrate_measured(m, options)), located)
    held_out: list[Localization] = []
    fold_options = replace(options, responses=False)  # not imaged with: not estimated
    for test in split:
        train = np.array([i for i, n in enumerate(numbers) if n not in test])
        held_out += evaluate(geometry_of(calibrate_measured(m, fold_options, train)), test)
    return CrossValidation(Evaluation(in_sample, settings), Evaluation(held_out, settings),
                           split)
