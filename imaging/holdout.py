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
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from acquisition.contracts.session import SessionReader
from acquisition.contracts.step_ids import pose_index
from calibration.errors import CalibrationInputError
from calibration.pipeline import (
    CalibrationOptions,
    CalibrationRun,
    Measurements,
    calibrate_measured,
    measure,
)

from .evaluate import (
    Evaluation,
    ImagingSettings,
    Localization,
    evaluate_session,
    session_recordings,
)
from .geometry import ArrayGeometry, geometry_from_dict
from .parallel import Mapper

MIN_TRAINING_POSES = 2
"""Poses each fold's calibration needs at least (12 sources: the joint fit's minimum)."""

FoldJob = tuple[Path, Measurements, CalibrationOptions, np.ndarray | None, list[int],
                ImagingSettings, ArrayGeometry | None]
"""The arguments of one `calibrate_and_image`: a cell of `cross_validate`."""


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
                   workers: int | None = 1, mapper: Mapper | None = None) -> CrossValidation:
    """In-sample and k-fold held-out CLEAN-SC localization of a session (module docstring).

    Args:
        options: the calibration's options (default: `micam calibrate`'s).
        truth: a simulated session's truth, to measure errors against it too.
        progress: called with (done, total) recordings over both evaluations.
        workers: processes for the imaging (see `evaluate_session`).
        mapper: runs the k + 1 calibrations, each with the imaging of its poses, elsewhere
            (e.g. as tasks on a Dask cluster; `workers` is then unused): the same numbers,
            bit for bit, as here. The measurements are still made here, once.
    """
    settings = settings or ImagingSettings()
    options = options or CalibrationOptions()
    session = Path(session).absolute()  # a mapper's workers may run in another directory
    reader = SessionReader(session)
    m = measure(session, options)
    numbers = [pose_index(p.step) for p in m.speakers.poses]
    located = [n for n in numbers if n is not None]
    split = fold_poses(located, folds)
    recorded = {pose: len(r) for pose, r in session_recordings(reader).items()}
    total = 2 * sum(recorded.get(pose, 0) for pose in located)
    fold_options = replace(options, responses=False)  # not imaged with: not estimated
    jobs: list[FoldJob] = [(session, m, options, None, located, settings, truth)] + [
        (session, m, fold_options, np.array([i for i, n in enumerate(numbers) if n not in test]),
         test, settings, truth) for test in split]
    done = 0

    def step(count: int, _total: int) -> None:
        if progress is not None:
            progress(done + count, total)

    results: Iterable[list[Localization]] = (
        mapper(calibrate_and_image, jobs) if mapper is not None else
        (calibrate_and_image(*job, workers=workers, progress=step) for job in jobs))
    evaluated: list[list[Localization]] = []
    for job, rows in zip(jobs, results, strict=True):
        evaluated.append(rows)
        done += sum(recorded.get(pose, 0) for pose in job[4])
        step(0, total)
    return CrossValidation(Evaluation(evaluated[0], settings),
                           Evaluation([r for rows in evaluated[1:] for r in rows], settings),
                           split)


def calibrate_and_image(session: Path, m: Measurements, options: CalibrationOptions,
                        train: np.ndarray | None, poses: list[int], settings: ImagingSettings,
                        truth: ArrayGeometry | None, workers: int | None = 1,
                        progress: Callable[[int, int], None] | None = None
                        ) -> list[Localization]:
    """One cell of `cross_validate`: the localizations of `poses`' recordings imaged with the
    calibration from the located poses `train` (indices into `m.speakers.poses`; None: all)."""
    geometry = geometry_of(calibrate_measured(m, options, train))
    return evaluate_session(SessionReader(session), geometry, settings, progress, workers,
                            poses=poses, truth=truth).rows
