"""The import description: one TOML file, the rig and array description of
acquisition/contracts/rig_description.py plus a `[recordings]` table naming the files (paths
relative to the TOML file), read and validated field by field.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationError, model_validator

from acquisition.contracts.bounded_files import UnreadableFile, read_bounded_text
from acquisition.contracts.config_model import ConfigModel
from acquisition.contracts.errors import UserError
from acquisition.contracts.rig_description import (
    CameraDescription,
    LayoutIds,
    LayoutPositions,
    LayoutTolerance,
    RigArrayDescription,
    layout_problems,
    problem_text,
)

MAX_SPEC_BYTES = 4_000_000
"""The import TOML: a description and a list of files, far below this."""
MAX_POSES = 1000
"""Most rig poses of one import (a calibration takes 10 to 200)."""


class ImportSpecError(UserError):
    """The import TOML or its files cannot make a session; the message says what to change."""


class BurstFile(ConfigModel):
    """A recording of one burst: a file, where in it the burst's recording starts and, for
    HDF5, which dataset holds it."""

    file: str = Field(examples=["pose00/speaker0.wav"],
                      description="path relative to the TOML file")
    start_sample: int = Field(default=0, ge=0, examples=[0],
                              description="first sample of this burst's recording in the file")
    dataset: str = Field(default="time_data", examples=["time_data"],
                         description="HDF5 only: the dataset of shape (samples, channels)")


FileRef = str | BurstFile
"""A burst recording: a file that holds exactly one recording, or a `BurstFile` table."""


class PoseFiles(ConfigModel):
    """One rig pose: every speaker's burst recording, in speaker order, and the cameras'
    images of the board."""

    bursts: tuple[FileRef, ...] = Field(
        min_length=1, examples=[["pose00/speaker0.wav", "pose00/speaker1.wav"]],
        description="one recording per speaker, in speaker order")
    images: dict[str, str] = Field(
        default_factory=dict, examples=[{"cam0": "pose00/cam0.png"}],
        description="camera name -> image file (a camera that missed the pose is left out)")


class RecordingFiles(ConfigModel):
    """The files of the session, paths relative to the TOML file."""

    references: tuple[FileRef, ...] = Field(
        min_length=1, examples=[["reference/speaker0.wav", "reference/speaker1.wav"]],
        description="the reference recording of each speaker (the reference microphone close "
                    "to it), in speaker order")
    refmic_images: dict[str, str] | None = Field(
        default=None, examples=[{"cam0": "refmic/cam0.png"}],
        description="images of the reference microphone on its stand touched by the rig's "
                    "reference mark (only with the reference microphone in the pose "
                    "recordings)")
    poses: tuple[PoseFiles, ...] = Field(min_length=1, max_length=MAX_POSES)


class ImportCamera(CameraDescription):
    """A camera of the import: as in the description, or with its known calibration given as
    a file (OpenCV YAML/JSON/XML, ROS camera_info or a micam result.json)."""

    intrinsics_file: str | None = Field(
        default=None, examples=["cam0_intrinsics.yaml"],
        description="a known calibration of this camera, relative to the TOML file")
    intrinsics_use: Literal["prior", "fixed"] = Field(
        default="prior", examples=["fixed"],
        description="how to use the file: 'fixed' as given, 'prior' weighted by intrinsics_std")
    intrinsics_std: tuple[float, float, float, float, float, float, float, float,
                          float] | None = Field(
        default=None, examples=[[0.5, 0.5, 0.5, 0.5, 0.002, 0.01, 1e-4, 1e-4, 0.02]],
        description="standard deviations of fx, fy, cx, cy (px), k1, k2, p1, p2, k3 for a "
                    "prior (default: the file's, if it is a micam result)")


class ImportLayout(ConfigModel):
    """The array's nominal layout as the import TOML gives it: a file (the maker's Acoular
    XML, or a micam result.json / truth.json), or the positions themselves as the description
    stores them (rig_description.KnownLayout)."""

    file: str | None = Field(
        default=None, examples=["array64.xml"],
        description="the layout's file, relative to the TOML file: an Acoular MicGeom XML "
                    '(microphone k named "Point k"), a micam result.json or truth.json')
    mic_ids: LayoutIds | None = None
    positions_m: LayoutPositions | None = None
    tolerance_m: LayoutTolerance = None

    def problems(self, channel_ids: list[int]) -> list[str]:
        """What is missing or contradictory, one line each (a file's content is checked
        when it is read)."""
        inline = self.mic_ids is not None or self.positions_m is not None
        if self.file is not None and inline:
            return ["layout: both file and mic_ids/positions_m are given; write only one of "
                    "them"]
        if self.file is not None:
            return []
        if self.mic_ids is None or self.positions_m is None:
            return ["layout: no positions; write file = \"array.xml\" (the maker's layout), "
                    "or mic_ids = [...] with positions_m = [[x, y, z], ...]"]
        return layout_problems(self.mic_ids, len(self.positions_m), channel_ids)


class ImportSpec(RigArrayDescription):
    """The import TOML: the rig and array description, the cameras (optionally with a known
    calibration file) and the recordings."""

    cameras: tuple[ImportCamera, ...] = Field(min_length=1,  # type: ignore[assignment]
                                              description="camera 0 (the frame) first")
    layout: ImportLayout | None = Field(  # type: ignore[assignment]
        default=None, description="the array's nominal layout, to check the wiring against")
    recordings: RecordingFiles
    session_id: str | None = Field(default=None, pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$",
                                   examples=["lab-2026-03-02"])

    @model_validator(mode="after")
    def _files_fit_the_description(self) -> ImportSpec:
        problems = self._import_problems()
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def _import_problems(self) -> list[str]:
        """What the import's own fields (recordings, cameras' files, layout) get wrong."""
        problems = []
        n = self.n_speakers
        rec = self.recordings
        if len(rec.references) != n:
            problems.append(f"recordings.references: {len(rec.references)} files for {n} "
                            "speakers; write one reference recording per speaker, in order")
        cameras = [c.name for c in self.cameras]
        for i, pose in enumerate(rec.poses):
            if len(pose.bursts) != n:
                problems.append(f"recordings.poses[{i}].bursts: {len(pose.bursts)} files for "
                                f"{n} speakers; write one recording per speaker, in order")
            unknown = sorted(set(pose.images) - set(cameras))
            if unknown:
                problems.append(f"recordings.poses[{i}].images: camera {unknown[0]!r} is not "
                                f"in cameras ({', '.join(cameras)}); write one of those names")
        if rec.refmic_images is not None:
            if self.reference.pose_recordings_column is None:
                problems.append(
                    "recordings.refmic_images: the reference microphone's image on its stand "
                    "is only of use when the pose recordings hold it; write "
                    "reference.pose_recordings_column = ..., or leave refmic_images out")
            if self.rig.reference_mark_m is None:
                problems.append("recordings.refmic_images: needs rig.reference_mark_m, the rig "
                                "point touched to the reference microphone; write it, e.g. "
                                "reference_mark_m = [-0.09, -0.06, 0.0]")
            unknown = sorted(set(rec.refmic_images) - set(cameras))
            if unknown:
                problems.append(f"recordings.refmic_images: camera {unknown[0]!r} is not in "
                                "cameras; write one of their names")
        for i, c in enumerate(self.cameras):
            if c.intrinsics_file is not None and c.intrinsics is not None:
                problems.append(f"cameras[{i}]: both intrinsics and intrinsics_file are given; "
                                "write only one of them")
            if (c.intrinsics_file is not None and c.intrinsics_use == "prior"
                    and c.intrinsics_std is None and not c.intrinsics_file.endswith(".json")):
                problems.append(f"cameras[{i}].intrinsics_std: a prior needs its standard "
                                "deviations; write intrinsics_std = [fx, fy, cx, cy, k1, k2, "
                                "p1, p2, k3], or intrinsics_use = 'fixed'")
        if self.layout is not None:
            problems += self.layout.problems([m for m, _, _ in self.microphones()])
        return problems


def load_spec(path: Path) -> ImportSpec:
    """Read and validate an import TOML.

    Raises:
        ImportSpecError: unreadable, not TOML, or invalid (one line per problem).
    """
    path = Path(path)
    if not (path.exists() or path.is_symlink()):
        raise ImportSpecError(f"import description {path} does not exist")
    try:
        document = tomllib.loads(read_bounded_text(path, MAX_SPEC_BYTES))
    except UnreadableFile as exc:
        raise ImportSpecError(f"import description: {exc}; an import description is a few "
                              "kilobytes of TOML") from None
    except (RecursionError, tomllib.TOMLDecodeError) as exc:
        raise ImportSpecError(f"{path} is not a readable TOML file: {exc}") from None
    try:
        return ImportSpec.model_validate(document)
    except ValidationError as exc:
        raise ImportSpecError(problem_text(f"import description {path}", exc, ImportSpec)
                              .rstrip("\n")) from None
