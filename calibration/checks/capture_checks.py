"""Mistakes of the wiring and of the playback, found in the recordings before any geometry
is fitted: dead, intermittent and inverted microphones, clipped bursts, speakers that did
not play or played distorted.

Each is a fact of the signals alone, so it is judged against the rest of the same session
(a microphone against the array, a burst against the session's bursts), never against a
fixed level that another lab's gains would break. What is found becomes a `Finding`; what
cannot be trusted is left out of every later stage (a microphone whole, or single
measurements), and an inverted microphone is corrected by correlating its recordings with
the opposite sign (`inverted_microphones`, then `measure_session_tofs(polarity=...)`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .distortion import ReferenceFloors, distorted_speakers, reference_floors
from ..errors import CalibrationInputError
from ..levels import CLIPPED_SAMPLES, DROPOUT_BLOCK, DROPOUT_DB
from ..result import Finding, FindingAction, FindingKind
from ..session_data import SessionData
from ..acoustic.times_of_flight import SessionTofs

DEAD_DB = 15.0
"""A microphone whose median correlation SNR over the session is this far (dB) below the
array's median microphone hears none of the bursts: dead, or its cable unplugged."""

SILENT_DB = 15.0
"""A burst whose median SNR over the array is this far (dB) below the session's median burst
was not played (a speaker disconnected, or its channel muted)."""

INVERTED_RATIO = 1.25
"""A microphone is taken to be wired inverted where, over the session, the median ratio of
its correlation's deepest trough to its highest peak around the direct sound exceeds this:
a capsule's correlation with the reference is a positive pulse with shallower side lobes
(ratio about 0.6), noise is symmetric (about 1), an inverted capsule's is the same pulse
upside down (about 1.7)."""

KEPT_SHARE = 0.5
"""Below this share of the microphones, or of the measurements, left after the mistakes
are taken out, nothing the calibration gives can be trusted: it refuses."""


class UntrustworthyCaptureError(CalibrationInputError):
    """So much of a capture is spoiled by its mistakes that no calibration of it can be
    trusted; the message names the mistakes found."""


@dataclass(frozen=True)
class CaptureVerdict:
    """What the checks found and what the calibration does about it.

    Attributes:
        findings: the mistakes, in the order found.
        kept: indices of the microphones the calibration keeps (the others are left out).
        left_out: (P, S, M) measurements not to use (clipped, dropped out, not played).
        unplayed: (P, S) bursts that were not played, or played distorted (their reference
            microphone's times of flight are not used either).
    """

    findings: list[Finding]
    kept: np.ndarray
    left_out: np.ndarray
    unplayed: np.ndarray


def _trough_to_peak(tofs: SessionTofs) -> np.ndarray:
    """(M,) median over the session of each microphone's correlation trough over its peak,
    around the direct sound (see `INVERTED_RATIO`)."""
    impulses = np.asarray(tofs.impulses, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = -impulses.min(axis=-1) / impulses.max(axis=-1)
    return np.nanmedian(np.where(np.isfinite(ratio), ratio, np.nan), axis=(0, 1))


def _mic_snr_deficit_db(tofs: SessionTofs) -> np.ndarray:
    """(M,) how far (dB) each microphone's median SNR lies below the array's median
    microphone (a channel holding zeros has no SNR: infinitely far)."""
    snr = np.where(np.isfinite(tofs.snr_db), tofs.snr_db, -np.inf)
    per_mic = np.median(snr, axis=(0, 1))
    return float(np.median(per_mic)) - per_mic


def dead_microphones(tofs: SessionTofs) -> np.ndarray:
    """Indices of the microphones that hear none of the bursts (`DEAD_DB`)."""
    return np.flatnonzero(_mic_snr_deficit_db(tofs) > DEAD_DB)


def inverted_microphones(tofs: SessionTofs) -> np.ndarray:
    """Indices of the live microphones whose correlations are upside down (`INVERTED_RATIO`):
    measured again with `polarity` -1 they correlate as the others do."""
    inverted = _trough_to_peak(tofs) > INVERTED_RATIO
    inverted[dead_microphones(tofs)] = False
    return np.flatnonzero(inverted)


def check_capture(data: SessionData, tofs: SessionTofs,
                  uncorrected: SessionTofs | None = None,
                  floors: ReferenceFloors | None = None) -> CaptureVerdict:
    """The mistakes of the wiring and the playback in `tofs` (every array over all M
    microphones of `data`), measured with the polarity that `inverted_microphones` found in
    `uncorrected` (None: nothing was inverted); `floors`: the reference recordings' (None:
    read from `data`)."""
    wiring = Wiring(data)
    findings: list[Finding] = []
    n_pose, n_speaker, n_mic = tofs.tof_s.shape
    left_out = np.zeros((n_pose, n_speaker, n_mic), dtype=bool)

    flipped = np.flatnonzero(tofs.polarity < 0)
    if flipped.size and uncorrected is not None:
        findings.append(wiring.finding(
            "inverted-microphone", "corrected", flipped,
            evidence=f"{wiring.names(flipped)} {_are(flipped)} wired with inverted polarity: "
                     f"{_their(flipped)} correlations with the reference are upside down (median trough "
                     f"over peak {_ratios(_trough_to_peak(uncorrected)[flipped])}, the "
                     f"array's {np.median(_trough_to_peak(uncorrected)):.2f}; corrected "
                     f"{_ratios(_trough_to_peak(tofs)[flipped])})",
            advice=f"{_their(flipped)} recordings were correlated with the opposite sign; "
                   "check the capsules' wiring (or the preamplifiers' phase switches)"))

    dead = dead_microphones(tofs)
    if dead.size:
        deficit = _mic_snr_deficit_db(tofs)[dead]
        findings.append(wiring.finding(
            "dead-microphone", "left out", dead,
            evidence=f"{wiring.names(dead)} {_are(dead)} silent: {_are_they(dead)} none of "
                     f"the bursts (correlation SNR {_decibels(deficit)} below the array's "
                     "median)",
            advice="left out: the result has no position for "
                   f"{'it' if dead.size == 1 else 'them'}; check the cables, connectors and "
                   "phantom power"))

    live = np.setdiff1d(np.arange(n_mic), dead)
    silent = _silent_bursts(tofs, live)
    if silent.any():
        left_out |= silent[:, :, None]
        for k in np.flatnonzero(silent.any(axis=0)):
            poses = [data.pose_steps[i] for i in np.flatnonzero(silent[:, k])]
            when = ("in any pose" if len(poses) == n_pose
                    else f"in {len(poses)} of {n_pose} poses")
            findings.append(Finding(
                kind="silent-speaker", action="left out", speakers=[int(k)], poses=poses,
                evidence=f"speaker {k} did not play {when}: the array heard no burst of it "
                         f"there (more than {SILENT_DB:g} dB below the session's others)",
                advice="those bursts were left out; check the speaker's cable and its "
                       "amplifier channel"))

    if floors is None:
        floors = reference_floors(data.references(), data.description.burst, data.fs)
    typical_db = floors.typical_floor_db()
    unplayed = silent.copy()
    for k in distorted_speakers(floors):
        unplayed[:, k] = True
        left_out[:, k] = True
        findings.append(Finding(
            kind="distorted-speaker", action="left out", speakers=[int(k)],
            evidence=f"speaker {k} is driven into distortion: its reference recording "
                     f"correlated with the MLS it played has spurious peaks all over, a floor "
                     f"{-floors.floor_db[k]:.0f} dB below its peak where the session's "
                     f"median speaker's lies {-typical_db:.0f} dB below",
            advice="its bursts were left out (correlated with its own distorted reference "
                   "recording its times of flight stay near the direct sound's, but not "
                   "quite); lower its amplifier's gain or the burst's amplitude"))

    clipped = tofs.rail_samples >= CLIPPED_SAMPLES
    clipped[:, :, dead] = False
    if clipped.any():
        left_out |= clipped
        mics = np.flatnonzero(clipped.any(axis=(0, 1)))
        findings.append(wiring.finding(
            "clipped-bursts", "left out", mics,
            poses=[data.pose_steps[i] for i in np.flatnonzero(clipped.any(axis=(1, 2)))],
            evidence=f"{int(clipped.sum())} recordings at {wiring.names(mics)} are clipped "
                     f"(at least {CLIPPED_SAMPLES} samples at full scale)",
            advice="those recordings were left out; lower the input gain of those channels "
                   "or the speakers' level, or move the rig further from the array"))

    dropped = tofs.dropout_share > 0
    dropped[:, :, dead] = False
    dropped &= ~silent[:, :, None]
    if dropped.any():
        left_out |= dropped
        mics = np.flatnonzero(dropped.any(axis=(0, 1)))
        findings.append(wiring.finding(
            "intermittent-microphone", "left out", mics,
            poses=[data.pose_steps[i] for i in np.flatnonzero(dropped.any(axis=(1, 2)))],
            evidence=f"{wiring.names(mics)} dropped out in {int(dropped.sum())} recordings "
                     f"(blocks of {DROPOUT_BLOCK} samples more than {DROPOUT_DB:g} dB below "
                     "the rest of the burst)",
            advice="those recordings were left out; check the connectors and cables of "
                   "those channels for a loose contact"))
    return CaptureVerdict(findings, live, left_out, unplayed)


def apply_verdict(data: SessionData, tofs: SessionTofs, verdict: CaptureVerdict
                  ) -> tuple[SessionData, SessionTofs]:
    """`data` and `tofs` without what `verdict` leaves out: its microphones gone, its
    measurements NaN (which every later stage skips). UntrustworthyCaptureError when less
    than `KEPT_SHARE` of the microphones or of the measurements remains."""
    n_mic = data.mic_ids.size
    kept_measurements = 1.0 - verdict.left_out[:, :, verdict.kept].sum() / verdict.left_out.size
    if verdict.kept.size < KEPT_SHARE * n_mic or kept_measurements < KEPT_SHARE:
        spoiled = "; ".join(f.evidence for f in verdict.findings)
        raise UntrustworthyCaptureError(
            f"the capture cannot be calibrated: {verdict.kept.size} of {n_mic} microphones "
            f"and {kept_measurements:.0%} of the measurements are usable ({spoiled}); fix "
            "the wiring and capture again")
    tof_s = np.where(verdict.left_out, np.nan, tofs.tof_s)
    std_s = np.where(verdict.left_out, np.nan, tofs.std_s)
    cleaned = replace(tofs, tof_s=tof_s, std_s=std_s,
                      reference_tof_s=np.where(verdict.unplayed, np.nan, tofs.reference_tof_s),
                      reference_std_s=np.where(verdict.unplayed, np.nan, tofs.reference_std_s))
    return data.with_microphones(verdict.kept), cleaned.with_microphones(verdict.kept)


def _silent_bursts(tofs: SessionTofs, live: np.ndarray) -> np.ndarray:
    """(P, S) bursts the live microphones did not hear (`SILENT_DB`)."""
    snr = np.where(np.isfinite(tofs.snr_db[:, :, live]), tofs.snr_db[:, :, live], -np.inf)
    per_burst = np.median(snr, axis=2)
    return per_burst < float(np.median(per_burst)) - SILENT_DB


class Wiring:
    """Where a session's microphones are wired, for the findings' words."""

    def __init__(self, data: SessionData) -> None:
        self.ids = data.mic_ids
        inputs = {column: (group.group, index) for group in data.description.channels
                  for index, column in enumerate(group.columns)}
        self.inputs = [inputs[int(c)] for c in data.mic_columns]

    def names(self, mics: np.ndarray) -> str:
        ids = [str(int(self.ids[i])) for i in mics]
        if len(ids) == 1:
            return f"microphone {ids[0]}"
        return f"microphones {', '.join(ids[:-1])} and {ids[-1]}"

    def finding(self, kind: FindingKind, action: FindingAction, mics: np.ndarray,
                evidence: str, advice: str,
                poses: list[str] | None = None) -> Finding:
        return Finding(kind=kind, action=action, microphones=[int(self.ids[i]) for i in mics],
                       channels=[f"{self.inputs[i][0]} input {self.inputs[i][1]}"
                                 for i in mics],
                       poses=poses or [], evidence=evidence, advice=advice)


def _are(mics: np.ndarray) -> str:
    return "is" if mics.size == 1 else "are"


def _their(mics: np.ndarray) -> str:
    return "its" if mics.size == 1 else "their"


def _are_they(mics: np.ndarray) -> str:
    return "it hears" if mics.size == 1 else "they hear"


def _ratios(values: np.ndarray) -> str:
    return ", ".join(f"{v:.2f}" for v in values)


def _decibels(values: np.ndarray) -> str:
    return ", ".join("no signal" if not np.isfinite(v) else f"{v:.0f} dB" for v in values)
