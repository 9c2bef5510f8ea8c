"""A worker's answer checked against its session before the daemon stores or publishes it.

Any process that can reach the jobs socket can claim to be a worker, so a result is evidence,
not truth. Before `calibration/result.json` is written (or `live.json`, or an event sent) the
broker checks that the answer describes the session the job was about: its session id, one
position for every microphone the session recorded (the ids and boards of its capture
configuration) and for no other (but those its findings left out, at most half), cameras
the session has, poses the session completed, and physically possible figures (finite numbers, a speed of sound of air, positions within
`MAX_DISTANCE_M` of camera 0). It cannot tell a careful forgery from a calibration; it stops a
broken or rogue worker from replacing a session's calibration with nonsense.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.session import SessionError, SessionReader
from acquisition.contracts.step_ids import is_pose_step
from acquisition.contracts.job_messages import LiveUpdate

SPEED_OF_SOUND_RANGE_M_S = (250.0, 450.0)
"""Air from -40 to 60 degC (306-366 m/s), with a margin for humidity and other gases."""
MAX_DISTANCE_M = 50.0
"""No microphone of a calibrated array is this far from camera 0."""
MAX_PIXEL = 1e6
"""No pixel coordinate, distance or angle of a live update is larger (an image is never a
million pixels wide)."""


class ResultRejected(ValueError):
    """The answer does not describe its session; the message says what is wrong."""


@dataclass(frozen=True)
class SessionFacts:
    """What an answer must agree with, read once from the session's journal."""

    session_id: str
    mic_boards: dict[int, str]  # microphone id -> board serial
    cameras: frozenset[str]
    poses: frozenset[str]  # completed pose steps

    @classmethod
    def read(cls, session: Path) -> SessionFacts:
        try:
            reader = SessionReader(session)
            capture = CaptureConfig.of_session(reader.capture, session)
        except SessionError as exc:
            raise ResultRejected(f"its session cannot be read to check it: {exc}") from None
        return cls(session_id=reader.session_id,
                   mic_boards={c.mic_id: c.board for c in capture.columns
                               if c.role == "mic" and c.mic_id is not None},
                   cameras=frozenset(c.name for c in capture.cameras),
                   poses=frozenset(s for s in reader.steps() if is_pose_step(s)))


def parse_result(data: bytes) -> dict[str, Any]:
    """result.json's bytes as a dict; ResultRejected for anything else (NaN included)."""

    def refuse_constant(name: str) -> float:
        raise ValueError(f"{name} is not a number a result may hold")

    try:
        result = json.loads(data, parse_constant=refuse_constant)
    except (ValueError, RecursionError) as exc:
        raise ResultRejected(f"it is not JSON: {exc}") from None
    if not isinstance(result, dict):
        raise ResultRejected(f"it is a JSON {type(result).__name__}, not an object")
    return result


def check_result(result: dict[str, Any], facts: SessionFacts) -> None:
    """Raise ResultRejected unless the final result `result` describes the session."""
    try:
        if result.get("session_id") != facts.session_id:
            raise ResultRejected(f"it is about session {result.get('session_id')!r}, not "
                                 f"{facts.session_id}")
        findings = result.get("findings", [])
        _check_microphones(((m["id"], m["position_m"], m["std_m"], m["board"])
                            for m in result["microphones"]), facts,
                           left_out=_named(findings, "left out"),
                           relabelled=_named(findings, "corrected", RELABELLING))
        _check_speed(result["speed_of_sound_m_s"])
        unknown = {c["name"] for c in result["cameras"]} - facts.cameras
        if unknown:
            raise ResultRejected(f"it names cameras the session does not have: {sorted(unknown)}")
        foreign = {p["step"] for p in result["poses"]} - facts.poses
        if foreign:
            raise ResultRejected(f"it uses poses the session did not complete: {sorted(foreign)}")
    except (KeyError, TypeError, AttributeError) as exc:
        raise ResultRejected(f"it is not a calibration result ({type(exc).__name__}: {exc})"
                             ) from None


def check_live(update: LiveUpdate, facts: SessionFacts) -> None:
    """Raise ResultRejected unless the live update describes the session (a subset of its
    microphones: the quick solve may leave some out)."""
    if update.session_id != facts.session_id:
        raise ResultRejected(f"it is about session {update.session_id!r}, not "
                             f"{facts.session_id}")
    _check_microphones(((m.id, m.position_m, m.std_m, None) for m in update.microphones),
                       facts, every=False)
    _check_speed(update.speed_of_sound_m_s)
    foreign = {p.step for p in update.poses_taken} - facts.poses
    if foreign:
        raise ResultRejected(f"it uses poses the session did not complete: {sorted(foreign)}")
    numbers = [x for p in update.poses_taken
               for x in (p.distance_m, p.azimuth_deg, p.elevation_deg)]
    if update.suggestion is not None:
        numbers += [x for px in (*update.suggestion.outline_px, *update.suggestion.speakers_px)
                    for x in px]
    if not all(math.isfinite(x) and abs(x) <= MAX_PIXEL for x in numbers):
        raise ResultRejected("its poses or its suggestion hold numbers that are not finite or "
                             f"beyond {MAX_PIXEL:g}")


RELABELLING = ("swapped-microphones", "shifted-boards")
"""Findings whose microphones the calibration relabelled (calibration.checks.layout_check): each is
recorded on the board its cable is really plugged into, which may be another board than the
session's channel map gives its id."""


def _named(findings: Any, action: str, kinds: tuple[str, ...] | None = None) -> set[int]:
    """The microphones that a result's findings of `kinds` (None: any) name with `action`
    ("left out": a dead microphone has no position); ResultRejected for findings that are not
    a list of findings."""
    if not isinstance(findings, list) or not all(isinstance(f, dict) for f in findings):
        raise ResultRejected("its findings are not a list of findings")
    named = [f.get("microphones", []) for f in findings if f.get("action") == action
             and (kinds is None or f.get("kind") in kinds)]
    if not all(isinstance(ids, list) and all(type(i) is int for i in ids) for ids in named):
        raise ResultRejected("its findings name microphones that are not ids")
    return {i for ids in named for i in ids}


def _check_microphones(mics: Iterable[tuple[Any, Any, Any, Any]], facts: SessionFacts,
                       every: bool = True, left_out: frozenset[int] | set[int] = frozenset(),
                       relabelled: frozenset[int] | set[int] = frozenset()) -> None:
    seen: set[int] = set()
    boards = set(facts.mic_boards.values())
    for mic_id, position, std, board in mics:
        if mic_id not in facts.mic_boards or mic_id in seen:
            raise ResultRejected(f"microphone {mic_id!r} is not one of the session's, or appears "
                                 "twice")
        seen.add(mic_id)
        moved = mic_id in relabelled and board in boards  # recorded on another board
        if board is not None and board != facts.mic_boards[mic_id] and not moved:
            raise ResultRejected(f"microphone {mic_id} is on board {facts.mic_boards[mic_id]}, "
                                 f"not {board!r}")
        if not (_finite_vector(position) and math.hypot(*position) <= MAX_DISTANCE_M):
            raise ResultRejected(f"microphone {mic_id}'s position {position!r} is not a "
                                 f"position within {MAX_DISTANCE_M:g} m of camera 0")
        if not (_finite_vector(std) and min(std) >= 0):
            raise ResultRejected(f"microphone {mic_id}'s std {std!r} is not three finite "
                                 "non-negative numbers")
    missing = set(facts.mic_boards) - seen - left_out
    if every and 2 * len(seen) < len(facts.mic_boards):  # the calibration refuses less
        raise ResultRejected(f"it places {len(seen)} of the session's "
                             f"{len(facts.mic_boards)} microphones, fewer than half")
    if every and missing:
        raise ResultRejected(f"it has no position for {len(missing)} of the session's "
                             f"{len(facts.mic_boards)} microphones (e.g. {min(missing)})")


def _check_speed(c: Any) -> None:
    low, high = SPEED_OF_SOUND_RANGE_M_S
    if not (isinstance(c, int | float) and low <= c <= high):
        raise ResultRejected(f"its speed of sound {c!r} m/s is not that of air ({low:g}-"
                             f"{high:g} m/s)")


def _finite_vector(v: Any) -> bool:
    return (isinstance(v, list | tuple) and len(v) == 3
            and all(isinstance(x, int | float) and math.isfinite(x) for x in v))
