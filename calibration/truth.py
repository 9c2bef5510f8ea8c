"""A truth file to compare a calibration with (`micam calibrate --truth`), checked up front.

A micam truth file is what `micam simulate` writes as truth.json (and what a lab that knows its
geometry can write by hand): `microphones` [{`id`, `position_m`}], `speed_of_sound_m_s`,
`cameras` [{`name`, `K`}] and optionally `board_latencies_s` {group: seconds}, all in the
camera-0 frame. Other keys are allowed (truth.json carries the whole simulated world). It is
checked against the session before any work, so that a file of another shape is an error that
says what is wrong, not a traceback after result.json is written.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from acquisition.contracts.bounded_files import (
    MAX_DOCUMENT_BYTES,
    UnreadableFile,
    read_bounded_text,
)
from acquisition.contracts.config_model import dotted
from kernel.rigid import RigidTransform

from .errors import CalibrationInputError
from .checks.layout_check import NominalLayout

SHAPE = ("a micam truth file has microphones = [{id, position_m}], speed_of_sound_m_s, "
         "cameras = [{name, K}] and optionally board_latencies_s, as `micam simulate` writes "
         "truth.json")


class TruthError(CalibrationInputError):
    """The truth file cannot be compared with this session; the message says why."""


class _Open(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)


class TruthMicrophone(_Open):
    id: int
    position_m: tuple[float, float, float]


class TruthCamera(_Open):
    name: str
    K: tuple[tuple[float, float, float], tuple[float, float, float],
             tuple[float, float, float]]


class TruthDocument(_Open):
    microphones: list[TruthMicrophone] = Field(min_length=1)
    speed_of_sound_m_s: float
    cameras: list[TruthCamera] = Field(min_length=1)
    board_latencies_s: dict[str, float] = Field(default_factory=dict)


def load_truth(path: Path, mic_ids: list[int], camera_names: list[str]) -> dict:
    """The truth document at `path`, checked to cover the session's microphones and cameras.

    Raises:
        TruthError: unreadable, not JSON, of another shape, or without some of the session's
            microphones or cameras.
    """
    try:
        document = json.loads(read_bounded_text(Path(path), MAX_DOCUMENT_BYTES))
    except UnreadableFile as exc:
        raise TruthError(f"truth file: {exc}") from None
    except (json.JSONDecodeError, RecursionError) as exc:
        raise TruthError(f"truth file {path} is not JSON ({exc}); {SHAPE}") from None
    try:
        truth = TruthDocument.model_validate(document)
    except ValidationError as exc:
        problems = "; ".join(f"{dotted(tuple(e['loc'])) or '(top level)'}: {e['msg']}"
                             for e in exc.errors()[:5])
        raise TruthError(f"truth file {path} is not a micam truth file ({problems}); "
                         f"{SHAPE}") from None
    known = {m.id for m in truth.microphones}
    missing = [i for i in mic_ids if i not in known]
    if missing:
        raise TruthError(f"truth file {path} lacks microphones {missing[:10]}"
                         f"{' ...' if len(missing) > 10 else ''} of this session; give the "
                         "truth of this array (microphone ids as in the session)")
    cameras = {c.name for c in truth.cameras}
    absent = [c for c in camera_names if c not in cameras]
    if absent:
        raise TruthError(f"truth file {path} has no camera {', '.join(absent)} (it has "
                         f"{', '.join(sorted(cameras))}); name the cameras as the session does")
    return document


def nominal_layout_of(truth: dict, build_error_m: float = 0.0005, seed: int = 0
                      ) -> NominalLayout:
    """The nominal layout of a simulated array, as its maker would give it: the truth's
    microphone positions (the simulated array is built exactly to them) off by
    `build_error_m` per axis (normal), in a frame of its own (a random rigid motion, so that
    nothing relies on the layout sharing the camera's frame); both drawn from `seed`."""
    ids = np.array([m["id"] for m in truth["microphones"]])
    positions = np.array([m["position_m"] for m in truth["microphones"]], dtype=np.float64)
    rng = np.random.default_rng(seed)
    own_frame = RigidTransform.from_rotvec(rng.normal(0, 0.5, 3), rng.normal(0, 0.3, 3))
    return NominalLayout(ids, own_frame.apply(positions + rng.normal(0, build_error_m,
                                                                     positions.shape)))
