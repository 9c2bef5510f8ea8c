"""The import's plan, its check and its session: one pass over the files serves both.

`prepare` reads the TOML and checks every field and every file's header. `contents` then
yields the steps one at a time with their files read and checked (`_files`); `check_import`
drops each step as it comes, `import_session` writes it. So `--check` makes every check the
import makes, in the same code, and the memory of either is one step's files, whatever the
number of poses.

The session is written into a hidden directory beside `out` and renamed into place only when
it is complete: an import that fails part way (a NaN in the last recording, a full disk,
Ctrl-C) removes what it wrote and leaves `out` as it was, so the same command can be run
again. Nothing that existed before the import is ever removed or overwritten.
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from acquisition.contracts.output_paths import new_directory_problem
from acquisition.contracts.positions_file import (
    PositionsFileError,
    positions_of,
    read_positions,
)
from acquisition.contracts.rig_description import (
    CameraDescription,
    KnownLayout,
    RigArrayDescription,
    problem_text,
)
from acquisition.contracts.session import (
    JOURNAL_NAME,
    SessionError,
    SessionExistsError,
    SessionWriter,
    fsync_dir,
    sha256_file,
)
from acquisition.contracts.session._atomic import make_dirs
from acquisition.contracts.step_ids import REFMIC_STEP, pose_step, reference_step

from ..intrinsics_file import IntrinsicsFileError, read_intrinsics
from ._files import _Recording, check_image, check_recording, inside, read_image
from ._spec import ImportSpec, ImportSpecError, load_spec


@dataclass(frozen=True)
class _Image:
    """A checked image of a step: its camera, the file, its path as written and TOML field."""

    camera: CameraDescription
    path: Path
    relative: str
    where: str


@dataclass(frozen=True)
class _Step:
    """A session step to write: its recordings (file name, recording, speaker) and images."""

    id: str
    recordings: tuple[tuple[str, _Recording, int], ...]
    images: tuple[_Image, ...]


def description_of(spec: ImportSpec, base: Path) -> RigArrayDescription:
    """The description the session stores: the spec's, with the cameras' intrinsics files
    and the layout's file read into values."""
    cameras = []
    for i, c in enumerate(spec.cameras):
        known = c.intrinsics
        if c.intrinsics_file is not None:
            where = f"cameras[{i}].intrinsics_file"
            try:
                known = read_intrinsics(inside(base, c.intrinsics_file, where), c.name,
                                        (c.width, c.height), c.intrinsics_use, c.intrinsics_std)
            except IntrinsicsFileError as exc:
                raise ImportSpecError(f"{where}: {exc} (write the path of another calibration, "
                                      "or leave intrinsics_file out to calibrate the camera "
                                      "from its images)") from None
        cameras.append(CameraDescription(name=c.name, width=c.width, height=c.height,
                                         intrinsics=known))
    fields = spec.model_dump(exclude={"cameras", "recordings", "session_id", "layout"})
    try:
        return RigArrayDescription.model_validate({**fields, "cameras": cameras,
                                                   "layout": _layout_of(spec, base)})
    except ValidationError as exc:
        raise ImportSpecError(problem_text("the imported description", exc,
                                           RigArrayDescription)) from None


def _layout_of(spec: ImportSpec, base: Path) -> KnownLayout | None:
    """The spec's nominal layout with its file (inside `base`) read into positions: every
    microphone the file places, sorted by id, named by the file's path as written.

    Raises:
        ImportSpecError: naming `layout.file`: a path out of `base`, a missing file, one that is
            not a geometry file, or one that lacks microphones of the channel map.
    """
    given = spec.layout
    if given is None:
        return None
    if given.file is None:  # the positions themselves (ImportLayout.problems checked them)
        return KnownLayout.model_validate(given.model_dump(exclude={"file"}))
    where = "layout.file"
    try:
        path = inside(base, given.file, where)
        positions = read_positions(path, "the layout")
        positions_of(positions, [m for m, _, _ in spec.microphones()], path, "the layout")
    except PositionsFileError as exc:
        raise ImportSpecError(f"{where}: {exc} (write the path of the array's layout, or leave "
                              "[layout] out to calibrate without checking the wiring)") from None
    ids = sorted(positions)
    return KnownLayout(mic_ids=tuple(ids),
                       positions_m=tuple((float(x), float(y), float(z))
                                         for x, y, z in (positions[i] for i in ids)),
                       tolerance_m=given.tolerance_m, source=given.file)


def plan(spec: ImportSpec, base: Path) -> list[_Step]:
    """Every step of the session, each file checked from its header (`_files`)."""
    rec = spec.recordings
    cameras = {c.name: c for c in spec.cameras}
    mic_columns = [c for _, c, _ in spec.microphones()]
    pose_last = max([*mic_columns, spec.reference.pose_recordings_column or 0])

    def images(files: dict[str, str], where: str) -> tuple[_Image, ...]:
        return tuple(_Image(cameras[camera], check_image(base, path, f"{where}.{camera}",
                                                         cameras[camera]),
                            path, f"{where}.{camera}")
                     for camera, path in files.items())

    steps = [
        _Step(reference_step(k), ((f"speaker_{k}.wav", check_recording(
            base, ref, f"recordings.references[{k}]", spec,
            spec.reference.reference_recordings_column), k),), ())
        for k, ref in enumerate(rec.references)
    ]
    if rec.refmic_images:
        steps.append(_Step(REFMIC_STEP, (), images(rec.refmic_images, "recordings.refmic_images")))
    for i, pose in enumerate(rec.poses):
        where = f"recordings.poses[{i}]"
        recordings = tuple(
            (f"speaker_{k}.wav", check_recording(base, ref, f"{where}.bursts[{k}]", spec,
                                                 pose_last), k)
            for k, ref in enumerate(pose.bursts))
        steps.append(_Step(pose_step(i), recordings, images(pose.images, f"{where}.images")))
    return steps


@dataclass(frozen=True)
class Prepared:
    """An import whose fields and file headers are checked: the description the session
    stores and its steps (their files are read by `contents`)."""

    spec: ImportSpec
    base: Path
    description: RigArrayDescription
    steps: list[_Step]

    @property
    def n_images(self) -> int:
        return sum(len(step.images) for step in self.steps)


@dataclass(frozen=True)
class StepContent:
    """One step's files as read and checked: images by camera, recordings by file name with
    their codes and per-column scale."""

    step: _Step
    images: dict[str, np.ndarray]
    recordings: dict[str, tuple[np.ndarray, list[float] | None]]


def prepare(spec_path: Path) -> Prepared:
    """Read the import TOML and check every field and every file's header.

    Raises:
        ImportSpecError: the TOML or a file is wrong.
    """
    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    base = spec_path.parent
    return Prepared(spec, base, description_of(spec, base), plan(spec, base))


def contents(p: Prepared) -> Iterator[StepContent]:
    """Each step with its files read and checked, one step at a time.

    Raises:
        ImportSpecError: a file's content is wrong (see `_files`).
    """
    for step in p.steps:
        yield StepContent(
            step,
            {image.camera.name: read_image(image.path, image.relative, image.where, image.camera)
             for image in step.images},
            {name: recording.codes() for name, recording, _ in step.recordings})


def check_import(spec_path: Path) -> Prepared:
    """Make every check the import makes, on every field and file, writing nothing; the
    memory it takes is one step's files.

    Raises:
        ImportSpecError: the TOML or a file is wrong.
    """
    p = prepare(spec_path)
    for _ in contents(p):
        pass
    return p


def import_session(spec_path: Path, out: Path,
                   on_step: Callable[[str], None] | None = None) -> Path:
    """Build a session in `out` from the import TOML at `spec_path` and its files.

    `out` must not exist, or be an empty directory (missing parents are made). The session is
    written beside it and renamed into place when complete (see the module docstring).

    Raises:
        ImportSpecError: the TOML or a file is wrong (`out` is left as it was).
        SessionExistsError: `out` holds a session.
        SessionError: `out` cannot be a new session directory, or the store refused a write
            (`out` is left as it was).
    """
    out = Path(out)
    _check_out(out)
    p = prepare(spec_path)
    try:
        if not out.parent.exists():
            make_dirs(out.parent)
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.importing-", dir=out.parent))
    except OSError as exc:
        raise SessionError(f"cannot create the session {out}: {exc}; choose a --out on a "
                           "writable disk") from None
    try:
        session = staging / out.name
        _write(p, Path(spec_path), session, on_step)
        _move_into_place(session, out)
    except OSError as exc:  # a source file that vanished, a disk that filled
        raise SessionError(f"the import into {out} stopped ({exc}); nothing of it was kept: "
                           "fix the cause and run it again") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out


def _check_out(out: Path) -> None:
    """Refuse an `out` that cannot become the new session directory, before any work."""
    if (out / JOURNAL_NAME).exists():
        raise SessionExistsError(f"{out} already holds a session")
    problem = new_directory_problem(out)
    if problem:
        raise SessionError(f"{out} {problem}")


def _write(p: Prepared, spec_path: Path, session: Path,
           on_step: Callable[[str], None] | None) -> None:
    """Write the whole session into `session` (a new directory) and stop it as a success."""
    writer = SessionWriter.create(session, capture=p.description.model_dump(mode="json"),
                                  session_id=p.spec.session_id)
    sources: dict[str, str] = {}
    with writer:
        for content in contents(p):
            step = content.step
            writer.begin_step(step.id)
            for image in step.images:
                writer.write_image(step.id, f"{image.camera.name}.png",
                                   content.images[image.camera.name],
                                   meta={"source": image.relative})
                sources[image.relative] = sha256_file(image.path).sha256
            for name, recording, speaker in step.recordings:
                codes, scale = content.recordings[name]
                source = recording.path.relative_to(p.base).as_posix()
                writer.write_recording(
                    step.id, name, codes, round(p.description.sample_rate_hz),
                    meta={"speaker": speaker, "source": source, "start_sample": recording.start,
                          "source_format": recording.source_format, "import_scale": scale})
                sources[source] = sha256_file(recording.path).sha256
            writer.end_step(step.id)
            if on_step is not None:
                on_step(step.id)
        writer.begin_step("import")
        writer.write_json("import", "import.json", {
            "description_toml": spec_path.read_text(encoding="utf-8"),
            "sources_sha256": sources,
        })
        writer.end_step("import")
        writer.stop("success")


def _move_into_place(session: Path, out: Path) -> None:
    """Rename the complete session to `out`, which must still be missing or empty."""
    try:
        os.rename(session, out)  # replaces an empty directory, never a file or anything else
    except OSError as exc:
        if exc.errno in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOTDIR, errno.EISDIR):
            raise SessionError(f"{out} was filled or replaced while the import ran; "
                               "nothing of it was changed: choose a new --out") from None
        raise SessionError(f"cannot move the session into {out}: {exc}") from None
    fsync_dir(out.parent)
