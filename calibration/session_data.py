"""What the calibration reads from a capture session, as plain arrays.

Calibration knows nothing of boards or USB: it reads the session directory through
`acquisition.session.SessionReader` and the frozen capture configuration stored in it. The
recordings are large (72 channels x 19 k samples x 6 speakers per pose), so they are loaded one
pose at a time (`pose_recordings`), never the whole session at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acquisition.air import AIR_FILE, AirReading
from acquisition.capture_config import CaptureConfig
from acquisition.session import SessionError, SessionReader


class CalibrationInputError(ValueError):
    """The session cannot be calibrated as it is (missing steps, wrong kind of session)."""


@dataclass(frozen=True)
class SessionData:
    """A session's layout and its completed steps, ready for calibration.

    Attributes:
        reader: the session reader.
        config: the frozen capture configuration.
        fs: sample rate, samples per second.
        mic_ids: (M,) microphone ids (the `mic_id` of the recording columns), in column order.
        mic_columns: (M,) recording column of each microphone.
        mic_boards: (M,) serial of the board that records each microphone.
        reference_column: the recording column of the reference microphone.
        pose_steps: the completed pose steps ("pose/0000", ...), in order.
        camera_names: the cameras, cam0 first.
    """

    reader: SessionReader
    config: CaptureConfig
    fs: float
    mic_ids: np.ndarray
    mic_columns: np.ndarray
    mic_boards: tuple[str, ...]
    reference_column: int
    pose_steps: tuple[str, ...]
    camera_names: tuple[str, ...]

    @property
    def n_speakers(self) -> int:
        return len(self.config.speakers)

    @property
    def speakers_rig_m(self) -> np.ndarray:
        """(n_speakers, 3) speaker positions in the rig frame."""
        return np.array([s.rig_position_m for s in self.config.speakers])

    def volts_per_code(self) -> np.ndarray:
        """(n_columns,) volts per code of every recording column."""
        return np.array([c.volts_per_code for c in self.config.columns])

    def references(self) -> np.ndarray:
        """(n_speakers, n_samples) float32 reference-microphone recording of every speaker."""
        rows = []
        for s in self.config.speakers:
            codes, _ = self.reader.read_recording(f"reference/{s.index}", f"speaker_{s.index}.wav")
            rows.append(codes[:, self.reference_column])
        return np.asarray(rows, dtype=np.float32)

    def pose_recordings(self, step: str) -> np.ndarray:
        """(n_speakers, n_columns, n_samples) float32 codes of one pose's recordings."""
        out = []
        for s in self.config.speakers:
            codes, _ = self.reader.read_recording(step, f"speaker_{s.index}.wav")
            out.append(codes.T)
        return np.asarray(out, dtype=np.float32)

    def air_readings(self) -> dict[str, AirReading]:
        """The air sensor's reading of every pose step that has one (step -> reading)."""
        steps = self.reader.steps()
        return {step: AirReading.model_validate(self.reader.read_json(step, AIR_FILE))
                for step in self.pose_steps if AIR_FILE in steps[step].files}

    def images(self, step: str) -> dict[str, np.ndarray]:
        """The images of a step by camera name (cameras whose image is missing are left out)."""
        files = self.reader.steps()[step].files
        return {name: self.reader.read_image(step, f"{name}.png")
                for name in self.camera_names if f"{name}.png" in files}


def load_session(path: Path, allow_interrupted: bool = False) -> SessionData:
    """Open a session for calibration, with clear errors for what is missing.

    An interrupted session is refused unless `allow_interrupted`, in which case its completed
    poses are used.
    """
    try:
        reader = SessionReader(Path(path))
    except SessionError as exc:
        raise CalibrationInputError(str(exc)) from None
    if reader.status != "complete" and not (allow_interrupted and reader.status == "interrupted"):
        raise CalibrationInputError(
            f"session {path} is {reader.status}, not complete; resume the capture first, or "
            "calibrate its completed poses with --allow-interrupted"
        )
    try:
        config = CaptureConfig.of_session(reader.capture, path)
    except SessionError as exc:
        raise CalibrationInputError(str(exc)) from None
    steps = reader.steps()
    missing = [f"reference/{s.index}" for s in config.speakers
               if f"reference/{s.index}" not in steps]
    if missing:
        raise CalibrationInputError(
            f"session {path} lacks the reference recordings {', '.join(missing)}; times of "
            "flight cannot be measured without them"
        )
    poses = tuple(sorted(s for s in steps if s.startswith("pose/")))
    if not poses:
        raise CalibrationInputError(f"session {path} has no completed pose to calibrate from")
    columns = config.columns
    mics = [(i, c) for i, c in enumerate(columns) if c.role == "mic"]
    reference = [i for i, c in enumerate(columns) if c.role == "reference"]
    if len(reference) != 1:
        raise CalibrationInputError(
            f"session {path} must have exactly one reference-microphone column; "
            f"it has {len(reference)}"
        )
    return SessionData(
        reader=reader,
        config=config,
        fs=config.sample_rate_hz,
        mic_ids=np.array([c.mic_id for _, c in mics]),
        mic_columns=np.array([i for i, _ in mics]),
        mic_boards=tuple(c.board for _, c in mics),
        reference_column=reference[0],
        pose_steps=poses,
        camera_names=tuple(c.name for c in config.cameras),
    )
