"""Mistakes of the microphone cables that only the array's nominal layout shows: two cables
swapped, or the column map off by whole boards.

A swapped cable leaves every recording as good as the others: the microphone it carries is
measured exactly, under the other microphone's id. Only the layout the array was built to
(the maker's design, an Acoular MicGeom XML, an earlier calibration) says which id belongs
where. So the measured geometry, fitted free of any prior, is compared with the layout after
the best rigid placement (Kabsch on the inliers, so that a few misplaced microphones do not
pull it), and the permutations a lab makes are tried: the column map shifted (by a whole
board's channels: its connectors plugged one board along; every cyclic shift is tried), then
exchanges among the microphones still off their nominal places (a pair swap, or a longer
rotation of cables, solved as an assignment). A permutation that brings every microphone within the
layout's tolerance is applied (the columns are relabelled, so the result carries each
position under its right id) and said; microphones off their places that no permutation
explains are noted; a layout that fits fewer than half the microphones under every
permutation is refused (it is not this array's, or not in metres).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from acquisition.contracts.rig_description import KnownLayout
from kernel.rigid import RigidTransform, kabsch

from .capture_checks import KEPT_SHARE, Wiring
from ..errors import CalibrationInputError
from ..result import Finding
from ..session_data import SessionData

LAYOUT_TOLERANCE_M = 0.005
"""How far (m) a microphone may lie from its nominal place, after the best rigid placement of
the layout, and still be taken for itself: a drilled or printed array holds its capsules to a
millimetre or two, a calibration measures them to a tenth, and the closest capsules of
practical arrays are centimetres apart, so a swapped cable moves a microphone far beyond it."""

ROBUST_FACTOR = 3.0
"""While the rigid placement is fitted, microphones further than this many times the median
distance (or the tolerance, if larger) from their nominal places are left out of it."""

ROBUST_ROUNDS = 5
"""Rounds of fitting the placement and leaving out the far microphones."""


class LayoutMismatchError(CalibrationInputError):
    """The nominal layout fits too few microphones under every permutation tried."""


@dataclass(frozen=True)
class NominalLayout:
    """The geometry the array was built to, in its own frame (any rigid placement).

    Attributes:
        ids: (N,) microphone ids it holds (at least every microphone of the session).
        positions_m: (N, 3) their nominal positions, metres.
        tolerance_m: how far a microphone may lie from its nominal place (`LAYOUT_TOLERANCE_M`).
    """

    ids: np.ndarray
    positions_m: np.ndarray
    tolerance_m: float = LAYOUT_TOLERANCE_M

    @classmethod
    def described(cls, known: KnownLayout, tolerance_m: float | None = None) -> NominalLayout:
        """The layout a session's description carries; `tolerance_m` (metres) replaces its
        own, which replaces `LAYOUT_TOLERANCE_M`."""
        tolerance = next(t for t in (tolerance_m, known.tolerance_m, LAYOUT_TOLERANCE_M)
                         if t is not None)
        return cls(np.array(known.mic_ids), np.array(known.positions_m, dtype=np.float64),
                   tolerance)

    def of(self, ids: np.ndarray) -> np.ndarray:
        """(len(ids), 3) the nominal positions of `ids`."""
        index = {int(i): k for k, i in enumerate(self.ids)}
        return self.positions_m[[index[int(i)] for i in ids]]


@dataclass(frozen=True)
class LayoutVerdict:
    """What the comparison with the layout found.

    Attributes:
        ids: (M,) the microphone id each column of the session records (the session's own ids
            where nothing was relabelled).
        findings: what was found (none: every microphone lies at its nominal place).
        distance_m: (M,) each microphone's distance from its nominal place after the
            relabelling (NaN where it has no position).
        renamed: the channel map's id -> the id recorded there, for every column of the
            session whose id changed (those left out before the check too, which follow a
            shifted map).
    """

    ids: np.ndarray
    findings: list[Finding]
    distance_m: np.ndarray
    renamed: dict[int, int]


@dataclass(frozen=True)
class _Placement:
    """The layout rigidly placed onto the measured positions under one labelling."""

    ids: np.ndarray
    distance_m: np.ndarray  # (M,) NaN where there is no position
    inliers: int


def check_layout(data: SessionData, measured_m: np.ndarray,
                 layout: NominalLayout) -> LayoutVerdict:
    """Compare the measured (M, 3) positions of `data`'s microphones (metres, any frame, NaN
    where unsolved) with `layout` and relabel what a permutation of cables explains.

    Raises:
        LayoutMismatchError: fewer than `KEPT_SHARE` of the positioned microphones lie within
            the tolerance under every permutation tried.
    """
    tol = layout.tolerance_m
    solved = np.all(np.isfinite(measured_m), axis=1)
    own = _placed(data.mic_ids, measured_m, solved, layout)
    shifts = [(k, _placed(ids, measured_m, solved, layout)) for k, ids in _column_shifts(data)]
    shift, best = max([(0, own), *shifts], key=lambda c: c[1].inliers)  # identity wins ties
    if best.inliers < KEPT_SHARE * solved.sum():
        raise LayoutMismatchError(
            f"the array's nominal layout does not fit the measured geometry: at most "
            f"{best.inliers} of {int(solved.sum())} microphones lie within "
            f"{1e3 * tol:g} mm of it under any rigid placement (the column map shifted "
            "tried too); is it this array's layout, in metres, microphone k "
            'named "Point k"?')
    far = np.flatnonzero(best.distance_m > tol)
    ids = _exchanged(best.ids, far, measured_m, layout, solved)
    final = _placed(ids, measured_m, solved, layout)
    wiring = Wiring(replace(data, mic_ids=final.ids))
    findings = []
    if shift:
        findings.append(_shift_finding(data, shift, own, final))
    moved = np.flatnonzero(ids != best.ids)
    moved = moved[np.argsort(ids[moved])]
    if moved.size:
        findings.append(_exchange_finding(wiring, moved, best, final))
    unexplained = np.flatnonzero(final.distance_m > tol)
    if unexplained.size:
        findings.append(_misplaced_finding(wiring, unexplained, final, tol))
    session = np.array([i for i, _, _ in data.description.microphones()])
    recorded = dict(zip(session.tolist(), np.roll(session, shift).tolist(), strict=True))
    recorded.update(zip(data.mic_ids.tolist(), final.ids.tolist(), strict=True))
    renamed = {int(a): int(b) for a, b in recorded.items() if a != b}
    return LayoutVerdict(final.ids, findings, final.distance_m, renamed)


def relabelled(finding: Finding, renamed: dict[int, int]) -> Finding:
    """An earlier finding (named by the channel map's ids) under the ids `renamed` gives,
    its evidence saying which microphone each renamed column really records."""
    moved = [i for i in finding.microphones if i in renamed]
    if not moved:
        return finding
    said = ", ".join(f"{i} records microphone {renamed[i]}" for i in moved)
    return finding.model_copy(update={
        "microphones": [renamed.get(i, i) for i in finding.microphones],
        "evidence": f"{finding.evidence} (named by the channel map; relabelled against the "
                    f"layout, the column of {said})"})


def _placed(ids: np.ndarray, measured_m: np.ndarray, solved: np.ndarray,
            layout: NominalLayout) -> _Placement:
    """`layout` under the labelling `ids`, placed robustly onto the solved positions."""
    nominal = layout.of(ids)
    use = solved.copy()
    distance = np.full(ids.size, np.nan)
    for _ in range(ROBUST_ROUNDS):
        if use.sum() < 3:
            break
        placed = kabsch(nominal[use], measured_m[use]).apply(nominal)
        distance = np.where(solved, np.linalg.norm(placed - measured_m, axis=1), np.nan)
        keep = solved & (distance <= max(layout.tolerance_m,
                                         ROBUST_FACTOR * float(np.nanmedian(distance))))
        if np.array_equal(keep, use):
            break
        use = keep
    return _Placement(ids, distance, int(np.sum(distance <= layout.tolerance_m)))


def _column_shifts(data: SessionData) -> list[tuple[int, np.ndarray]]:
    """(s, ids) for every cyclic shift of the session's column map by s = 1 .. N-1 columns
    (N: the session's microphones, in column order): each column records the microphone that
    the description puts s columns before it. A column map off by one board is the shift by
    that board's channels; every shift is tried, since each costs one rigid fit."""
    session = np.array([i for i, _, _ in data.description.microphones()])
    position = {int(c): p for p, (_, c, _) in enumerate(data.description.microphones())}
    at = np.array([position[int(c)] for c in data.mic_columns])
    return [(s, session[(at - s) % session.size]) for s in range(1, session.size)]


def _exchanged(ids: np.ndarray, far: np.ndarray, measured_m: np.ndarray,
               layout: NominalLayout, solved: np.ndarray) -> np.ndarray:
    """`ids` with the far microphones relabelled among themselves where each then lies within
    the tolerance (an assignment of their measured positions to their nominal places, placed
    by the others; only whole cycles of cables that all fit are kept)."""
    far = far[solved[far]]
    if far.size < 2:
        return ids
    near = np.setdiff1d(np.flatnonzero(solved), far)
    nominal = layout.of(ids)
    placed = kabsch(nominal[near], measured_m[near]).apply(nominal[far])
    cost = np.linalg.norm(measured_m[far][:, None] - placed[None], axis=2)
    rows, cols = linear_sum_assignment(cost)
    fits = cost[rows, cols] <= layout.tolerance_m
    target = dict(zip(rows.tolist(), cols.tolist(), strict=True))
    out = ids.copy()
    for start in range(far.size):
        cycle = [start]
        while target[cycle[-1]] != start:
            cycle.append(target[cycle[-1]])
        if len(cycle) > 1 and min(cycle) == start and all(fits[c] for c in cycle):
            for c in cycle:
                out[far[c]] = ids[far[target[c]]]
    return out


def _mm(values: np.ndarray) -> str:
    return ", ".join(f"{1e3 * v:.1f}" for v in values) + " mm"


def _shift_finding(data: SessionData, shift: int, own: _Placement,
                   shifted: _Placement) -> Finding:
    n = len(data.description.microphones())
    signed = shift if shift <= n // 2 else shift - n
    widths = {len(g.columns) for g in data.description.channels}
    board = f" (one board's {abs(signed)} channels)" if abs(signed) in widths else ""
    return Finding(
        kind="shifted-boards", action="corrected",
        microphones=sorted(int(i) for i in shifted.ids[shifted.ids != own.ids]),
        evidence=f"the column map looks shifted by {signed:+d} columns{board}: as described, "
                 f"the microphones lie a median {1e3 * np.nanmedian(own.distance_m):.1f} mm "
                 "from their nominal places; with each column given to the microphone the "
                 f"description puts {abs(signed)} columns {'before' if signed > 0 else 'after'} "
                 f"it, {1e3 * np.nanmedian(shifted.distance_m):.2f} mm",
        advice="the columns were relabelled (each position is under the microphone that "
               "was recorded); check which board input each connector is plugged into, or "
               "correct the channel map of the description")


def _exchange_finding(wiring: Wiring, moved: np.ndarray, before: _Placement,
                      after: _Placement) -> Finding:
    swapped = moved.size == 2
    how = "look swapped" if swapped else "look exchanged among their cables"
    finding = wiring.finding(
        "swapped-microphones", "corrected", moved,
        evidence=f"{wiring.names(moved)} {how}: they lie {_mm(before.distance_m[moved])} "
                 "from their nominal places; with their columns exchanged "
                 f"{_mm(after.distance_m[moved])}",
        advice="their columns were relabelled (each position is under the microphone that "
               "was recorded)")
    return finding.model_copy(update={
        "advice": finding.advice + f"; check the cables at {', '.join(finding.channels)}"})


def _misplaced_finding(wiring: Wiring, far: np.ndarray, placement: _Placement,
                       tol: float) -> Finding:
    return wiring.finding(
        "misplaced-microphones", "noted", far,
        evidence=f"{wiring.names(far)} lie {_mm(placement.distance_m[far])} from their "
                 f"nominal places (tolerance {1e3 * tol:g} mm), and no exchange of cables "
                 "explains it",
        advice="their measured positions are kept; check that they sit where the layout "
               "says (and the layout itself), and their cables")
