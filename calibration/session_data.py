"""What the calibration reads from a capture session, as plain arrays.

Calibration knows nothing of boards or USB: it reads the session directory through
`acquisition.contracts.session.SessionReader` and the session's rig and array description
(acquisition/contracts/rig_description.py). A session that `micam import` built stores the description
itself; a session micam's acquisition captured stores its capture configuration, from which
the description is derived (`CaptureConfig.description`). The recordings are large (72
channels x 19 k samples x 6 speakers per pose), so they are loaded one pose at a time
(`pose_recordings`), never the whole session at once.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from acquisition.contracts.capture_config import CaptureConfig
from acquisition.contracts.config_model import describe_problems
from acquisition.contracts.errors import UserError
from acquisition.contracts.rig_description import (
    DESCRIPTION_KIND,
    RigArrayDescription,
    RigDescription,
    validate_description,
)
from acquisition.contracts.session import SessionError, SessionReader
from acquisition.contracts.step_ids import is_pose_step, reference_step
from kernel.air import AIR_FILE, AirReading

from .errors import CalibrationInputError
from .levels import full_scale_of


@dataclass(frozen=True)
class SessionData:
    """A session's layout and its completed steps, ready for calibration.

    Attributes:
        reader: the session reader.
        description: what calibration knows of the session (rig, array, cameras, air).
        fs: sample rate, samples per second.
        mic_ids: (M,) microphone ids, in column order.
        mic_columns: (M,) recording column of each microphone.
        mic_boards: (M,) clock/latency group of each microphone (a board's serial in a micam
            capture).
        reference_column: the column of the pose recordings that records the reference
            microphone on its stand, or None if the pose recordings do not hold it.
        reference_recording_column: its column in the reference recordings.
        pose_steps: the completed pose steps ("pose/0000", ...), in order.
        camera_names: the cameras, cam0 first.
    """

    reader: SessionReader
    description: RigArrayDescription
    fs: float
    mic_ids: np.ndarray
    mic_columns: np.ndarray
    mic_boards: tuple[str, ...]
    reference_column: int | None
    reference_recording_column: int
    pose_steps: tuple[str, ...]
    camera_names: tuple[str, ...]

    @property
    def rig(self) -> RigDescription:
        """The rig: board pattern, speakers and their priors (speaker_tolerance_m,
        acoustic_centre_m, acoustic_centre_std_m, print_scale_std)."""
        return self.description.rig

    @property
    def reference_group(self) -> str:
        """The clock/latency group of the reference microphone: the latency gauge."""
        return self.description.reference.group

    @property
    def n_speakers(self) -> int:
        return self.description.n_speakers

    @property
    def n_samples(self) -> int:
        """Samples per channel of one recording (the burst layout)."""
        return self.description.burst.n_samples

    @property
    def speakers_rig_m(self) -> np.ndarray:
        """(n_speakers, 3) nominal speaker positions in the rig frame."""
        return np.array(self.rig.speakers_m, dtype=np.float64)

    @property
    def reference_distances_m(self) -> np.ndarray:
        """(n_speakers,) the reference microphone's distance from each speaker in the
        reference recordings."""
        return np.array(self.description.reference_distances_m())

    def mic_volts_per_unit(self) -> np.ndarray:
        """(M,) volts per recorded unit of every microphone's column (ones where the
        description does not say: then every column is taken to have the same)."""
        scale: dict[int, float] = {}
        for group in self.description.channels:
            if group.volts_per_unit is not None:
                scale.update(zip(group.columns, group.volts_per_unit, strict=True))
        return np.array([scale.get(int(c), 1.0) for c in self.mic_columns])

    def full_scale(self) -> float:
        """The full scale of the recordings, in codes (`calibration.levels.full_scale_of`),
        read off the first speaker's reference recording (a session's recordings share one
        format)."""
        codes, _ = self.reader.read_recording(reference_step(0), "speaker_0.wav")
        return full_scale_of(codes)

    def with_microphones(self, kept: np.ndarray) -> SessionData:
        """This session with the microphones `kept` (indices into M) alone: the others are
        left out of every later stage, as if the array had none of them."""
        return replace(self, mic_ids=self.mic_ids[kept], mic_columns=self.mic_columns[kept],
                       mic_boards=tuple(self.mic_boards[i] for i in kept))

    def references(self, samples: slice = slice(None)) -> np.ndarray:
        """(n_speakers, n) float32 reference-microphone recording of every speaker (the
        `samples` of each)."""
        rows = []
        for k in range(self.n_speakers):
            codes, _ = self.reader.read_recording(reference_step(k), f"speaker_{k}.wav")
            rows.append(codes[samples, self.reference_recording_column])
        return np.asarray(rows, dtype=np.float32)

    def pose_recordings(self, step: str, columns: np.ndarray | None = None,
                        samples: slice = slice(None)) -> np.ndarray:
        """(n_speakers, n_columns, n) float32 codes of one pose's recordings: every column or
        `columns`, all samples or `samples` (converted alone: a burst's steady period is half
        of its recording)."""
        out: np.ndarray | None = None
        for k in range(self.n_speakers):
            codes, _ = self.reader.read_recording(step, f"speaker_{k}.wav")
            part = codes[samples] if columns is None else codes[samples][:, columns]
            if out is None:
                out = np.empty((self.n_speakers, *part.shape[::-1]), dtype=np.float32)
            out[k] = part.T
        assert out is not None  # a rig has speakers
        return out

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


def session_description(reader: SessionReader) -> RigArrayDescription:
    """The rig and array description of a session: stored as it is by `micam import`,
    derived from the capture configuration of a micam capture.

    Raises:
        CalibrationInputError: neither validates, with one line per problem.
    """
    capture = reader.capture
    try:
        if capture.get("kind") == DESCRIPTION_KIND:
            return validate_description(capture, f"session {reader.path}: its description")
        config = CaptureConfig.of_session(capture, reader.path)
        return config.description(_image_sizes(reader))
    except ValidationError as exc:  # a valid configuration whose description is not
        problems = "; ".join(describe_problems(exc, RigArrayDescription))
        raise CalibrationInputError(f"session {reader.path}: its description: {problems}"
                                    ) from None
    except UserError as exc:  # SessionError, DescriptionError
        raise CalibrationInputError(str(exc)) from None


def _image_sizes(reader: SessionReader) -> dict[str, tuple[int, int]]:
    """(width, height) of each camera's images, from the first completed image of each."""
    sizes: dict[str, tuple[int, int]] = {}
    for record in reader.steps().values():
        for name, file in record.files.items():
            if file.role == "image":
                sizes.setdefault(name.removesuffix(".png"),
                                 (int(file.meta["width"]), int(file.meta["height"])))
    return sizes


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
    description = session_description(reader)
    steps = reader.steps()
    missing = [reference_step(k) for k in range(description.n_speakers)
               if reference_step(k) not in steps]
    if missing:
        raise CalibrationInputError(
            f"session {path} lacks the reference recordings {', '.join(missing)}; times of "
            "flight cannot be measured without them"
        )
    poses = tuple(sorted(s for s in steps if is_pose_step(s)))
    if not poses:
        raise CalibrationInputError(f"session {path} has no completed pose to calibrate from")
    _check_recordings(reader, description, poses)
    mics = description.microphones()
    return SessionData(
        reader=reader,
        description=description,
        fs=description.sample_rate_hz,
        mic_ids=np.array([m for m, _, _ in mics]),
        mic_columns=np.array([c for _, c, _ in mics]),
        mic_boards=tuple(g for _, _, g in mics),
        reference_column=description.reference.pose_recordings_column,
        reference_recording_column=description.reference.reference_recordings_column,
        pose_steps=poses,
        camera_names=tuple(c.name for c in description.cameras),
    )


def _check_recordings(reader: SessionReader, description: RigArrayDescription,
                      poses: tuple[str, ...]) -> None:
    """Every recording the calibration reads exists, at the description's sample rate and
    length, with the columns the description names."""
    mic_columns = [c for _, c, _ in description.microphones()]
    pose_columns = max([*mic_columns, description.reference.pose_recordings_column or 0])
    needs = [(reference_step(k), f"speaker_{k}.wav",
              description.reference.reference_recordings_column)
             for k in range(description.n_speakers)]
    needs += [(step, f"speaker_{k}.wav", pose_columns)
              for step in poses for k in range(description.n_speakers)]
    steps = reader.steps()
    for step, name, last_column in needs:
        file = steps[step].files.get(name)
        if file is None or file.role != "recording":
            raise CalibrationInputError(f"session {reader.path}: step {step} has no "
                                        f"recording {name}")
        meta = file.meta
        problem = None
        if meta.get("n_channels", 0) <= last_column:
            problem = (f"has {meta.get('n_channels')} columns, but the description reads "
                       f"column {last_column}")
        elif meta.get("n_samples") != description.burst.n_samples:
            problem = (f"has {meta.get('n_samples')} samples, the burst layout "
                       f"{description.burst.n_samples}")
        elif meta.get("sample_rate_hz") != round(description.sample_rate_hz):
            problem = (f"is sampled at {meta.get('sample_rate_hz')} Hz, the description says "
                       f"{description.sample_rate_hz:g}")
        if problem:
            raise CalibrationInputError(f"session {reader.path}: {step}/{name} {problem}; "
                                        "the session and its description disagree")
