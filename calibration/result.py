"""The calibration result: result.json (same keys as the simulator's truth.json) and exports.

Comparing a result with the truth is one line because both use
`{"microphones": [{"id", "position_m"}], "speed_of_sound_m_s", "cameras", "poses"}`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal
from xml.sax.saxutils import quoteattr

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from acquisition.contracts.positions_file import (
    PositionsFileError,
    positions_of,
    read_positions,
)
from acquisition.contracts.session import write_atomic

from .errors import CalibrationInputError


class PriorFileError(CalibrationInputError):
    """A prior geometry file cannot be read, or lacks the session's microphones; the message
    names the file and what is wrong."""

Vector3 = tuple[float, float, float]


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class MicrophoneResult(_Model):
    id: int
    position_m: Vector3
    std_m: Vector3 = Field(description="standard deviation along x, y, z (camera-0 frame)")
    board: str
    residual_rms_s: float
    n_measurements: int
    delay_s: float | None = Field(
        default=None, description="the microphone's own delay (capsule and channel group "
        "delay) relative to its board's latency, when the joint fit estimated it")
    delay_std_s: float | None = None


class TransformResult(_Model):
    """x_to = R(rotvec) x_from + t_m."""

    rotvec: Vector3
    t_m: Vector3


class CameraResult(_Model):
    name: str
    width: int
    height: int
    K: list[list[float]]
    dist: list[float]
    from_cam0: TransformResult
    reprojection_rms_px: float
    images_used: int
    images_without_board: list[str]
    intrinsics_std: list[float] | None = Field(
        default=None, description="std of fx, fy, cx, cy (px), k1, k2, p1, p2, k3")
    corner_noise_px: float | None = Field(
        default=None, description="the camera's corner noise per pixel coordinate, estimated "
        "from the camera calibration's residuals with the degrees of freedom its fit absorbs "
        "(calibration.camera.corner_noise); the joint fit weights the corners by it")
    corner_noise_std_px: float | None = None
    corner_noise_corners: int | None = Field(
        default=None, description="corners it was estimated from (the views of the pool)")
    view_corner_noise_px: dict[str, float] = Field(
        default_factory=dict, description="the views whose noise differs from the camera's "
        "(a blurred or distant pose), by step: their own, px per coordinate")


class PoseResult(_Model):
    index: int
    step: str
    camera: str = Field(description="the camera whose image located the rig, or \"times of "
                                    "flight\" where no camera did and its bursts placed it")
    rig_to_cam0: TransformResult
    speakers_m: list[Vector3]
    speakers_std_m: list[Vector3]
    reprojection_rms_px: float | None = Field(
        description="RMS reprojection error of the image that located the rig; null where its "
                    "times of flight placed it")


class SpeedOfSoundReference(_Model):
    """The paper's IV-G fit: camera distances to the reference microphone against its TOFs."""

    speed_of_sound_m_s: float
    speed_of_sound_std_m_s: float
    n: int
    residual_rms_m: float
    reference_microphone_m: Vector3


class ResidualStats(_Model):
    rms_s: float
    median_abs_s: float
    n_measurements: int
    n_outliers: int


class TofQuality(_Model):
    median_snr_db: float
    p05_snr_db: float
    median_peak_to_sidelobe_db: float
    median_predicted_std_s: float | None = Field(
        description="median of the located times of flight's predicted std, seconds; None "
                    "when more than half are infinite (too little signal to predict one)")
    weighting: Literal["compact", "matched", "phat"] | None = Field(
        default=None, description="the correlations' spectral weighting (None: not recorded)")
    echo_ratio: float | None = Field(
        default=None, description="the correlations' energy after the direct sound over that "
                                  "before it: 1 in free field with flat capsules, far above "
                                  "with reflections")


SpeedOfSoundFrom = Literal["reference_microphone", "known", "solved", "joint_fit"]
"""Where a c comes from: the reference-microphone fit (paper IV-G), a known c (measured air
temperature or c) weighting the solver's, the solver alone, or the joint fit."""


class CameraFrozenResult(_Model):
    """The solution with the cameras calibrated first and then frozen (the joint fit's start),
    kept beside the joint one: their difference is what the cameras' errors cost."""

    microphones: list[MicrophoneResult]
    speed_of_sound_from: SpeedOfSoundFrom | None = None
    speed_of_sound_m_s: float
    speed_of_sound_std_m_s: float
    latency_s: dict[str, float]
    latency_std_s: dict[str, float]
    focal_px: dict[str, tuple[float, float]] = Field(description="fx, fy per camera")
    focal_std_px: dict[str, tuple[float, float]]


class LentReferenceResult(_Model):
    """A speaker whose own reference recording was spoiled (a swapped cable, the reference
    microphone misplaced), measured on another speaker's instead."""

    speaker: int
    reference_of: int = Field(description="the speaker whose reference recording its bursts "
                              "were correlated with")
    emission_delay_s: float = Field(description="its sound's delay after that speaker's, as "
                                    "fitted (driver, amplifier and cable; 0 for a twin)")
    emission_delay_std_s: float


class RigFitResult(_Model):
    """What the joint fit found of the rig: where each speaker's sound comes from (rig frame:
    the stated position plus the fitted offset, the acoustic centre included) and the scale
    of the printed pattern relative to its stated square size."""

    speakers_rig_m: list[Vector3]
    speakers_rig_std_m: list[Vector3]
    offsets_m: list[Vector3] = Field(description="fitted minus stated position, rig frame")
    print_scale: float
    print_scale_std: float
    acoustic_centre_off_axis_m: float = Field(
        default=0.0, description="b: off axis at angle theta the speakers' acoustic centre "
        "sits b (1 - cos theta) further out along the rig's normal")
    acoustic_centre_off_axis_std_m: float = 0.0
    lent_references: list[LentReferenceResult] = Field(default_factory=list)


class JointFitResult(_Model):
    """Diagnostics of the optical-acoustic bundle adjustment (calibration.solve.bundle)."""

    sigmas: dict[str, float] = Field(
        description="estimated noise: px per coordinate for a camera's corners, a factor on "
                    "the predicted std for the times of flight")
    corner_outliers: dict[str, int]
    tof_outliers: int
    reference_tof_outliers: int
    chi2_per_dof: float
    iterations: int
    reference_microphone_m: Vector3 | None = Field(
        default=None, description="the reference microphone on its stand (None when the pose "
                                  "recordings do not hold it)")
    reference_microphone_std_m: Vector3 | None = None
    speed_of_sound_per_pose_m_s: list[float] | None = Field(
        default=None, description="c during each located pose, in the order of `poses`, "
        "when c was fitted per pose (the air drifting)")
    speed_of_sound_per_pose_std_m_s: list[float] | None = None


class MicrophoneResponse(_Model):
    """One microphone's response relative to the array (recorded = gain e^(j phase) x ideal),
    per band of `MicrophoneResponsesResult.frequencies_hz`."""

    id: int
    gain: list[float]
    phase_rad: list[float]
    gain_std: list[float]
    phase_std_rad: list[float]


class MicrophoneResponsesResult(_Model):
    """Every microphone's complex response against frequency, relative to the array's median
    gain and mean phase, after the board latencies (calibration.acoustic.responses). The phase holds
    the microphone's own delay (`microphones[].delay_s`): apply one or the other."""

    frequencies_hz: list[float]
    microphones: list[MicrophoneResponse]
    n_sources: int


FindingKind = Literal["dead-microphone", "intermittent-microphone", "inverted-microphone",
                      "swapped-microphones", "shifted-boards", "misplaced-microphones",
                      "clipped-bursts", "silent-speaker", "swapped-speakers",
                      "misplaced-speaker", "moved-pose", "hidden-board", "motion-blur",
                      "glare", "mjpeg", "distorted-speaker", "misplaced-reference-microphone",
                      "close-reflection"]
FindingAction = Literal["corrected", "left out", "noted"]


class Finding(_Model):
    """A mistake of the capture that the calibration found in the recordings or the images:
    what it is, where, the evidence, what the calibration did about it and what to do."""

    kind: FindingKind
    action: FindingAction = Field(
        description="corrected: the calibration undid it (a polarity, columns relabelled); "
        "left out: the measurements concerned were not used; noted: used, but worth a look")
    microphones: list[int] = Field(default_factory=list, description="microphone ids")
    channels: list[str] = Field(default_factory=list,
                                description="where those microphones are wired")
    speakers: list[int] = Field(default_factory=list)
    poses: list[str] = Field(default_factory=list, description="pose steps concerned")
    cameras: list[str] = Field(default_factory=list, description="cameras concerned")
    evidence: str
    advice: str = Field(description="what the calibration did about it, and what to check or "
                                    "do before the next capture")

    def line(self) -> str:
        """The finding as one line: what and its evidence, then what was done and what to
        do (`advice` says both)."""
        return f"{self.evidence}; {self.advice}"


class BoardBowResult(_Model):
    """The printed board's sag out of its plane (calibration.camera.board_bow)."""

    sag_m: float = Field(description="the inner-corner grid's centre out of the plane of its "
                         "corners, metres (+: out of the printed face)")
    sag_std_m: float
    n_views: int


class CalibrationResult(_Model):
    schema_version: int = 1
    session_id: str
    method: str
    microphones: list[MicrophoneResult]
    speed_of_sound_m_s: float
    speed_of_sound_std_m_s: float
    speed_of_sound_reference: SpeedOfSoundReference | None
    speed_of_sound_from: SpeedOfSoundFrom | None = None
    speed_of_sound_known_m_s: tuple[float, float] | None = Field(
        default=None, description="the known c and its std (m/s) the calibration was given")
    latency_s: dict[str, float]
    latency_std_s: dict[str, float]
    cameras: list[CameraResult]
    poses: list[PoseResult]
    residuals: ResidualStats
    tof_quality: TofQuality
    timings_s: dict[str, float]
    notes: list[str]
    latency_gauge_board: str | None = Field(
        default=None, description="the board whose latency is 0 (records the reference mic)")
    camera_frozen: CameraFrozenResult | None = None
    joint_fit: JointFitResult | None = None
    rig: RigFitResult | None = None
    microphone_responses: MicrophoneResponsesResult | None = None
    findings: list[Finding] = Field(
        default_factory=list, description="the capture's mistakes found, in the order found")
    board_bow: BoardBowResult | None = None

    def left_out_microphones(self) -> set[int]:
        """The microphones that a finding left out whole: the result has no position for
        them."""
        placed = {m.id for m in self.microphones}
        return {i for f in self.findings if f.action == "left out"
                for i in f.microphones if i not in placed}

    def positions(self) -> np.ndarray:
        return np.array([m.position_m for m in self.microphones])

    def write(self, path: Path) -> None:
        """Write result.json atomically (temporary name, fsync, rename, directory fsync)."""
        data = self.model_dump_json(indent=1).encode()
        write_atomic(Path(path), lambda fh: fh.write(data), replace=True)


def write_acoular_xml(result: CalibrationResult, path: Path, name: str = "micam") -> None:
    """The microphone geometry as Acoular's MicGeom XML (`<MicArray><pos Name x y z/>`),
    positions in metres in the camera-0 frame, in microphone-id order. Microphone k is named
    "Point k" (micam's one numbering, from 0); Acoular reads the positions in document order
    and ignores the names, so its channel i is the i-th microphone by id."""
    lines = ['<?xml version="1.0" encoding="utf-8"?>', f"<MicArray name={quoteattr(name)}>"]
    for mic in sorted(result.microphones, key=lambda m: m.id):
        x, y, z = mic.position_m
        lines.append(f'  <pos Name="Point {mic.id}" x="{x:.6f}" y="{y:.6f}" z="{z:.6f}"/>')
    lines.append("</MicArray>")
    path.write_text("\n".join(lines) + "\n")


def write_acoular_calib_xml(result: CalibrationResult, path: Path,
                            name: str = "micam") -> None:
    """The microphones' relative sensitivities as Acoular's calibration XML
    (`<Calib><pos Name factor/>`, read by `acoular.Calib(file=...)` in document order), in
    microphone-id order, microphone k named "Point k" as in `write_acoular_xml`.

    Acoular multiplies each channel by its factor, so the factor is 1 / gain, the gain being
    the median over the bands of `microphone_responses` (Acoular's calibration of time data
    is one number per channel; the phases stay in result.json).

    Raises:
        ValueError: the result has no microphone responses.
    """
    if result.microphone_responses is None:
        raise ValueError("the result has no microphone responses (calibrate with the joint "
                         "fit to estimate them)")
    gain = {r.id: float(np.median(r.gain)) for r in result.microphone_responses.microphones}
    lines = ['<?xml version="1.0" encoding="utf-8"?>', f"<Calib name={quoteattr(name)}>"]
    for mic in sorted(result.microphones, key=lambda m: m.id):
        lines.append(f'  <pos Name="Point {mic.id}" factor="{1.0 / gain[mic.id]:.6f}"/>')
    lines.append("</Calib>")
    path.write_text("\n".join(lines) + "\n")


def compare_with_truth(result: CalibrationResult, truth: dict,
                       camera_frozen: bool = False) -> dict[str, float]:
    """Errors of a result (or of its camera-frozen solution) against a simulator's
    truth.json: microphone errors (metres), the speed-of-sound error (m/s), the largest
    relative focal-length error and the largest board-latency error (seconds, relative to the
    gauge board) when the result names its gauge board."""
    part: CameraFrozenResult | CalibrationResult = result
    focal = {c.name: (c.K[0][0], c.K[1][1]) for c in result.cameras}
    if camera_frozen:
        if result.camera_frozen is None:
            raise ValueError("the result has no camera-frozen solution (joint fit switched off)")
        part = result.camera_frozen
        focal = dict(result.camera_frozen.focal_px)
    true_pos = {m["id"]: np.array(m["position_m"]) for m in truth["microphones"]}
    errors = np.array([np.linalg.norm(np.array(m.position_m) - true_pos[m.id])
                       for m in part.microphones])
    true_K = {c["name"]: c["K"] for c in truth["cameras"]}
    out = {
        "mean_mic_error_m": float(errors.mean()),
        "median_mic_error_m": float(np.median(errors)),
        "max_mic_error_m": float(errors.max()),
        "speed_of_sound_error_m_s": part.speed_of_sound_m_s - truth["speed_of_sound_m_s"],
        "max_focal_error_rel": max(abs(f / true_K[name][axis][axis] - 1.0)
                                   for name, fxy in focal.items()
                                   for axis, f in enumerate(fxy)),
    }
    true_lat = truth.get("board_latencies_s", {})
    if result.latency_gauge_board in true_lat:
        gauge = true_lat[result.latency_gauge_board]
        out["max_latency_error_s"] = max(abs(v - (true_lat[b] - gauge))
                                         for b, v in part.latency_s.items())
    return out


def load_prior_positions(path: Path, mic_ids: np.ndarray) -> np.ndarray:
    """Microphone positions (len(mic_ids), 3), metres, of a known geometry, in `mic_ids` order:
    a result.json, a truth.json or an Acoular MicGeom XML
    (acquisition.contracts.positions_file).

    Raises:
        PriorFileError: naming the file and what is wrong (unreadable, not one of those
            formats, a position that is not three finite numbers, missing microphones).
    """
    what = "the prior geometry"
    try:
        return positions_of(read_positions(path, what), mic_ids, path, what)
    except PositionsFileError as exc:
        raise PriorFileError(str(exc)) from None
