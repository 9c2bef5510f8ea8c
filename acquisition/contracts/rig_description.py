"""The rig and array description: everything calibration needs to know, and nothing more.

Calibration reads a session through this description only: the printed board (its corners,
square size and which colour its origin square has, or a marker), the speakers' nominal
positions and how well they are known, the reference microphone (which column records it in
the reference recordings, and in the pose recordings if it does there at all, its distance from
each speaker, its clock/latency group), the channel map (microphone id, recording column,
clock/latency group), the sample rate, the burst layout (`BurstLayout`, whose fields the
capture's burst shares: acquisition/contracts/burst.py), the cameras by name and image size,
and what the user measured (air temperature or speed of sound, a known camera calibration).

It holds no hardware: board models, serials, input ranges, output wiring, a pose count or a
camera's device id are the acquisition's business (acquisition/contracts/capture_config.py). A micam
session carries its capture configuration, from which `CaptureConfig.description` derives this;
a session built by `micam import` carries this description itself (its `kind` says so).

Why here, beside capture_config: both are contracts of a session between acquisition (which
writes sessions, `micam import` included) and calibration (which reads them); this module needs
only pydantic, so calibration and sim import it without the daemon or the USB driver.

Every refusal names the field, says what is wrong and what to write instead: pydantic's own
checks through `config_model.describe_problems` (which adds each field's example), the
cross-field checks below in the same `field: problem; write ...` form.
"""

from __future__ import annotations

import re
from typing import Annotated, Final, Literal

from pydantic import Field, FiniteFloat, ValidationError, model_validator

from kernel.air import AirReading, SpeedOfSoundPrior

from .burst import BurstLayout
from .config_model import ConfigModel, describe_problems
from .errors import UserError

DESCRIPTION_KIND: Final = "rig-and-array"
"""The `kind` of a description stored as a session's capture (a capture configuration has
no `kind`), so that a reader knows which of the two a session carries."""

NAME_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_.-]*"
"""Camera and group names: plain names (a camera's name is its image file's name)."""

CAMERA_MODEL_COEFFICIENTS = 5
"""micam's lens model: OpenCV's k1, k2, p1, p2, k3 (the paper's equation 4)."""

_NAMES_ITS_FIELD = re.compile(
    r"(rig|air|burst|channels|reference|cameras|layout)[\w.\[\], ]*: ")
"""A cross-field problem of this module: it starts with the fields it is about."""


class DescriptionError(UserError):
    """A description that does not validate; the message has one line per problem."""


class RigDescription(ConfigModel):
    """The calibration rig: its printed board, its speakers, and how well both are known.

    Frame (the paper's, see sim.geometry): origin at an extreme inner corner of the printed
    board, X along the side with `corners_x` inner corners, Y along the side with `corners_y`,
    Z out of the printed face. The tolerances are priors of the calibration, not corrections:
    it fits each speaker's position on the rig and the print's scale, held to the stated values
    with these standard deviations.
    """

    corners_x: int = Field(ge=3, le=100, examples=[6],
                           description="inner corners along the rig's X axis (OpenCV's "
                                       "detectors need at least 3)")
    corners_y: int = Field(ge=3, le=100, examples=[9],
                           description="inner corners along the rig's Y axis (OpenCV's "
                                       "detectors need at least 3)")
    square_m: float = Field(gt=0, le=1.0, examples=[0.03],
                            description="side of one printed square, metres")
    origin_square: Literal["dark", "light"] = Field(
        default="dark", examples=["dark"],
        description="colour of the square between the origin corner and its neighbours along "
                    "+X and +Y (it resolves the board's half-turn ambiguity)")
    marker_square: tuple[int, int] | None = Field(
        default=None, examples=[[1, 2]],
        description="a square (index along X, along Y, from the origin square 0, 0) with a "
                    "round dot of the other colour at its centre; needed when the pattern looks "
                    "the same after a half-turn")
    speakers_m: tuple[tuple[float, float, float], ...] = Field(
        min_length=1, examples=[[[-0.06, 0.0, -0.0025], [0.21, 0.0, -0.0025]]],
        description="nominal position of each speaker in the rig frame, metres, in speaker "
                    "order")
    reference_mark_m: tuple[float, float, float] | None = Field(
        default=None, examples=[[-0.09, -0.06, 0.0]],
        description="the rig point touched to the reference microphone on its stand for the "
                    "'refmic' image (only needed with that image)")
    speaker_tolerance_m: float = Field(
        default=3e-4, ge=0, le=0.01, examples=[3e-4],
        description="build tolerance: standard deviation, per axis in the board plane, of each "
                    "speaker's position about its stated one (m)")
    acoustic_centre_m: float = Field(
        default=0.0, ge=-0.02, le=0.02, examples=[0.0],
        description="expected offset of each speaker's acoustic centre from its stated "
                    "position along the board normal, + out of the printed face (m)")
    acoustic_centre_std_m: float = Field(
        default=5e-3, ge=0, le=0.05, examples=[5e-3],
        description="standard deviation of that offset, per speaker (m)")
    print_scale_std: float = Field(
        default=2e-3, ge=0, le=0.05, examples=[2e-3],
        description="relative standard deviation of the printed pattern's scale about the "
                    "stated square size (0.002: within about 0.2 %)")
    speaker_diameter_m: float | None = Field(
        default=None, gt=0, le=0.5, examples=[0.026],
        description="the speakers' diameter: their off-axis roll-off is then taken out of "
                    "the microphones' estimated gains")

    @model_validator(mode="after")
    def _pattern_is_unambiguous(self) -> RigDescription:
        problems = rig_problems(self)
        if problems:
            raise ValueError("\n".join(problems))
        return self


def rig_problems(rig: RigDescription, where: str = "rig") -> list[str]:
    """Why the board's corner order could not be told from its image, one line each."""
    nx, ny = rig.corners_x, rig.corners_y
    if nx == ny:
        return [f"{where}.corners_x, {where}.corners_y: a square grid ({nx} x {ny}) has no "
                "side OpenCV can tell apart, so its corner order turns by quarter turns; "
                "print a board with different counts and write them (e.g. corners_x = 6, "
                "corners_y = 9)"]
    problems = []
    if rig.marker_square is not None:
        i, j = rig.marker_square
        if not (0 <= i < nx - 1 and 0 <= j < ny - 1):
            problems.append(
                f"{where}.marker_square: square {[i, j]} is not between inner corners (its "
                f"indices run 0..{nx - 2} along X and 0..{ny - 2} along Y); write one of those")
        elif (i, j) == (nx - 2 - i, ny - 2 - j):
            problems.append(
                f"{where}.marker_square: square {[i, j]} is the board's centre, which a "
                "half-turn keeps in place; put the dot in a square off the centre and write "
                "that one")
    elif (nx + ny) % 2 == 0:
        problems.append(
            f"{where}.corners_x, {where}.corners_y: a {nx} x {ny} pattern has the same colours "
            "after a half-turn, so the corner order (and every speaker) would be ambiguous; "
            "use a board with one even and one odd count (write e.g. corners_x = 6, "
            "corners_y = 9), or print a dot in one square and write marker_square = [i, j]")
    return problems


class ChannelGroup(ConfigModel):
    """Recording columns sampled with one latency (one board, one interface): the microphones
    they record. A latency is fitted per group, relative to the reference microphone's."""

    group: str = Field(pattern=f"^{NAME_PATTERN}$", examples=["board0"],
                       description="name of the clock/latency group (a board, an interface)")
    columns: tuple[int, ...] = Field(
        min_length=1, examples=[[0, 1, 2, 3, 4, 5]],
        description="recording columns (0-based) of this group's microphones")
    mic_ids: tuple[int, ...] = Field(
        min_length=1, examples=[[0, 1, 2, 3, 4, 5]],
        description="microphone id recorded in each of those columns, in the same order")
    volts_per_unit: tuple[float, ...] | None = Field(
        default=None, examples=[[0.000305, 0.000305, 0.000305, 0.000305, 0.000305, 0.000305]],
        description="what one recorded unit of each of those columns stands for, volts (the "
                    "input range over the codes' full scale); leave it out if every column of "
                    "the session has the same (the microphones' relative gains need it only "
                    "where ranges differ)")

    @model_validator(mode="after")
    def _one_scale_per_column(self) -> ChannelGroup:
        if self.volts_per_unit is not None and len(self.volts_per_unit) != len(self.columns):
            raise ValueError(f"volts_per_unit: {len(self.volts_per_unit)} values for "
                             f"{len(self.columns)} columns; write one per column")
        if self.volts_per_unit is not None and min(self.volts_per_unit) <= 0:
            raise ValueError("volts_per_unit: every value must be positive; write the volts "
                             "one recorded unit stands for")
        return self


class ReferenceMicrophone(ConfigModel):
    """The reference microphone (paper IV-C): close to each speaker in turn for the reference
    recordings, and on its stand during the poses when it is recorded there too."""

    group: str = Field(pattern=f"^{NAME_PATTERN}$", examples=["board0"],
                       description="the clock/latency group of the column that records it "
                                   "(its latency is the gauge: 0)")
    reference_recordings_column: int = Field(
        ge=0, examples=[0],
        description="the column of the reference recordings that holds it")
    pose_recordings_column: int | None = Field(
        default=None, ge=0, examples=[72],
        description="the column of the pose recordings that holds it on its stand; leave it "
                    "out if it is not recorded during the poses")
    distance_from_speaker_m: float | tuple[float, ...] = Field(
        default=0.002, examples=[0.002],
        description="its distance from the speaker in the reference recordings, metres: one "
                    "value for all speakers or one per speaker")


class KnownIntrinsics(ConfigModel):
    """A camera calibration known from elsewhere (OpenCV's model: pixels, k1 k2 p1 p2 k3)."""

    use: Literal["prior", "fixed"] = Field(
        default="prior", examples=["prior"],
        description="'fixed': used as given; 'prior': combined with what the images say, "
                    "weighted by `std`")
    camera_matrix: tuple[tuple[float, float, float], tuple[float, float, float],
                         tuple[float, float, float]] = Field(
        examples=[[[1000.0, 0.0, 640.0], [0.0, 1000.0, 480.0], [0.0, 0.0, 1.0]]],
        description="K: fx, 0, cx / 0, fy, cy / 0, 0, 1 in pixels")
    distortion: tuple[float, float, float, float, float] = Field(
        default=(0.0, 0.0, 0.0, 0.0, 0.0), examples=[[-0.08, 0.05, 0.0, 0.0, 0.0]],
        description="k1, k2, p1, p2, k3")
    std: tuple[float, float, float, float, float, float, float, float, float] | None = Field(
        default=None, examples=[[0.5, 0.5, 0.5, 0.5, 0.002, 0.01, 1e-4, 1e-4, 0.02]],
        description="standard deviations of fx, fy, cx, cy (px), k1, k2, p1, p2, k3")


class CameraDescription(ConfigModel):
    """A camera: its name (its images are <name>.png) and image size."""

    name: str = Field(pattern=f"^{NAME_PATTERN}$", examples=["cam0"])
    width: int = Field(gt=0, le=100_000, examples=[1280], description="image width, pixels")
    height: int = Field(gt=0, le=100_000, examples=[960], description="image height, pixels")
    intrinsics: KnownIntrinsics | None = None


class KnownAir(ConfigModel):
    """What was measured of the air during the session: a temperature (with, if measured, the
    relative humidity) or a speed of sound, each with its standard deviation."""

    temperature_c: float | None = Field(default=None, ge=-40, le=60, examples=[21.5])
    temperature_std_c: float | None = Field(default=None, ge=0, le=20, examples=[0.2])
    relative_humidity: float | None = Field(
        default=None, ge=0, le=1, examples=[0.45],
        description="0..1; without it any humidity is possible (about +-0.6 m/s at 20 degC)")
    relative_humidity_std: float | None = Field(default=None, ge=0, le=1, examples=[0.03])
    speed_of_sound_m_s: float | None = Field(default=None, ge=300, le=380, examples=[343.6])
    speed_of_sound_std_m_s: float | None = Field(default=None, ge=0, le=20, examples=[0.1])

    @model_validator(mode="after")
    def _one_quantity_with_its_std(self) -> KnownAir:
        problems = air_problems(self)
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def speed_of_sound_prior(self) -> SpeedOfSoundPrior:
        """(c, standard deviation) in m/s: the measured c, or Cramer's c of the measured air
        (kernel.air) with the temperature's and the humidity's std carried through
        (humidity unknown: 0.5 +- 0.5)."""
        if self.speed_of_sound_m_s is not None:
            return SpeedOfSoundPrior(self.speed_of_sound_m_s,
                                     float(self.speed_of_sound_std_m_s or 0.0))
        humid = self.relative_humidity is not None
        return AirReading(
            temperature_c=float(self.temperature_c or 0.0),
            temperature_std_k=max(float(self.temperature_std_c or 0.0), 1e-9),
            relative_humidity=self.relative_humidity if self.relative_humidity is not None else 0.5,
            relative_humidity_std=(float(self.relative_humidity_std or 0.0) if humid
                                   else 0.5),
            pressure_std_pa=2_000.0,
        ).speed_of_sound()

    def source(self) -> str:
        """Where the prior comes from, for a person."""
        if self.speed_of_sound_m_s is not None:
            return (f"measured speed of sound {self.speed_of_sound_m_s:.2f} ± "
                    f"{self.speed_of_sound_std_m_s:.2f} m/s")
        humidity = ("humidity unknown" if self.relative_humidity is None
                    else f"relative humidity {100 * self.relative_humidity:.0f} ± "
                         f"{100 * float(self.relative_humidity_std or 0.0):.0f} %")
        return (f"air temperature {self.temperature_c:.2f} ± {self.temperature_std_c:.2f} degC, "
                f"{humidity}")


def air_problems(air: KnownAir, where: str = "air") -> list[str]:
    """What is missing or contradictory in a known-air table, one line each."""
    has_t = air.temperature_c is not None
    has_c = air.speed_of_sound_m_s is not None
    if has_t and has_c:
        return [f"{where}: both temperature_c and speed_of_sound_m_s are given; write only the "
                "one you measured (with its std)"]
    if not (has_t or has_c):
        return [f"{where}: nothing measured; write temperature_c = ... with "
                "temperature_std_c = ..., or speed_of_sound_m_s = ... with "
                "speed_of_sound_std_m_s = ... (or leave [air] out)"]
    name, std = (("temperature", air.temperature_std_c) if has_t
                 else ("speed_of_sound", air.speed_of_sound_std_m_s))
    unit = "c" if has_t else "m_s"
    if std is None:
        return [f"{where}.{name}_std_{unit}: missing; write how well it is known, e.g. "
                f"{name}_std_{unit} = {0.2 if has_t else 0.1}"]
    if air.relative_humidity is not None and air.relative_humidity_std is None:
        return [f"{where}.relative_humidity_std: missing; write how well the humidity is "
                "known, e.g. relative_humidity_std = 0.03"]
    if air.relative_humidity is not None and not has_t:
        return [f"{where}.relative_humidity: only meaningful with temperature_c; write the "
                "temperature too, or leave the humidity out"]
    return []


MAX_LAYOUT_MICROPHONES = 10_000
"""Most microphones a nominal layout may hold (the largest arrays have a few thousand)."""

LayoutIds = Annotated[tuple[int, ...], Field(
    min_length=1, max_length=MAX_LAYOUT_MICROPHONES, examples=[[0, 1, 2]],
    description="the microphone ids the layout places (every id of the channel map, and "
                "possibly more)")]
LayoutPositions = Annotated[tuple[tuple[FiniteFloat, FiniteFloat, FiniteFloat], ...], Field(
    min_length=1, max_length=MAX_LAYOUT_MICROPHONES,
    examples=[[[0.0, 0.0, 0.0], [0.04, 0.0, 0.0], [0.0, 0.04, 0.0]]],
    description="the nominal position of each of those microphones, in the same order, "
                "metres, in the array's own frame (any rigid placement)")]
LayoutTolerance = Annotated[float | None, Field(
    default=None, gt=0, le=0.1, examples=[0.005],
    description="how far a microphone may lie from its nominal place and still be taken "
                "for itself, metres (default 0.005)")]


class KnownLayout(ConfigModel):
    """The array's nominal layout: where each microphone was built to be (the maker's design).

    A swapped microphone cable, or a column map off by a board, leaves every recording as good
    as the others: only the layout the array was built to shows which id belongs where. The
    calibration compares its measured geometry with this one (calibration.checks.layout_check) and
    relabels the columns a permutation of cables explains. Stored in the description itself
    (an import reads its file into these values), so that a session carries it wherever it
    is moved.
    """

    mic_ids: LayoutIds
    positions_m: LayoutPositions
    tolerance_m: LayoutTolerance = None
    source: str | None = Field(
        default=None, max_length=1000, examples=["array64.xml"],
        description="where the positions come from (a file's name), for a person")


def layout_problems(ids: tuple[int, ...], n_positions: int, channel_ids: list[int],
                    where: str = "layout") -> list[str]:
    """What keeps a nominal layout (`ids` with `n_positions` positions) from placing every
    microphone of the channel map (`channel_ids`), one line each."""
    problems = []
    if len(ids) != n_positions:
        problems.append(f"{where}.positions_m: {n_positions} positions for {len(ids)} "
                        "microphone ids; write one position [x, y, z] per id, in the same order")
    twice = sorted({i for i in ids if ids.count(i) > 1})
    if twice:
        problems.append(f"{where}.mic_ids: microphone {twice[0]} is placed twice; write each "
                        "microphone's id once")
    missing = sorted(set(channel_ids) - set(ids))
    if missing:
        problems.append(f"{where}.mic_ids: microphones {missing[:10]}"
                        f"{' ...' if len(missing) > 10 else ''} of the channel map are not in "
                        "the layout; write the nominal position of every microphone")
    return problems


class RigArrayDescription(ConfigModel):
    """What calibration knows of a session: rig, array, recordings' layout, cameras, air."""

    kind: Literal["rig-and-array"] = DESCRIPTION_KIND
    schema_version: Literal[1] = 1
    sample_rate_hz: float = Field(gt=0, le=10_000_000, examples=[48000],
                                  description="samples per second of every recording")
    rig: RigDescription
    channels: tuple[ChannelGroup, ...] = Field(
        min_length=1, description="the channel map, one table per clock/latency group")
    reference: ReferenceMicrophone
    burst: BurstLayout
    cameras: tuple[CameraDescription, ...] = Field(min_length=1,
                                                   description="camera 0 (the frame) first")
    air: KnownAir | None = None
    layout: KnownLayout | None = Field(
        default=None, description="the array's nominal layout, to check the wiring against "
                                  "(swapped cables, a column map off by a board)")

    @model_validator(mode="after")
    def _consistent(self) -> RigArrayDescription:
        problems = self.consistency_problems()
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def consistency_problems(self) -> list[str]:
        """Problems between fields (each names its field, what is wrong, what to write)."""
        problems: list[str] = []
        columns: dict[int, str] = {}
        mic_ids: dict[int, str] = {}
        groups: set[str] = set()
        for g, entry in enumerate(self.channels):
            where = f"channels[{g}]"
            if entry.group in groups:
                problems.append(f"{where}.group: {entry.group!r} is named twice; write each "
                                "group once, in one table with all its columns")
            groups.add(entry.group)
            if len(entry.columns) != len(entry.mic_ids):
                problems.append(
                    f"{where}.mic_ids: {len(entry.mic_ids)} ids for {len(entry.columns)} "
                    "columns; write one microphone id per column, in the same order")
            for column in entry.columns:
                if column < 0:
                    problems.append(f"{where}.columns: column {column} is negative; write "
                                    "columns counting from 0")
                elif column in columns:
                    problems.append(f"{where}.columns: column {column} is already in "
                                    f"{columns[column]}; write each column once (it records one "
                                    "microphone)")
                columns[column] = where
            for mic in entry.mic_ids:
                if mic in mic_ids:
                    problems.append(f"{where}.mic_ids: microphone {mic} is already in "
                                    f"{mic_ids[mic]}; write each microphone's id once")
                mic_ids[mic] = where
        ref = self.reference
        if ref.pose_recordings_column in columns:
            problems.append(
                f"reference.pose_recordings_column: column {ref.pose_recordings_column} "
                f"records a microphone in {columns[ref.pose_recordings_column]}; write the "
                "column that holds the reference microphone on its stand, or leave the key out "
                "if it is not recorded during the poses")
        given = ref.distance_from_speaker_m
        distances = given if isinstance(given, tuple) else (given,)
        if isinstance(given, tuple) and len(given) != self.n_speakers:
            problems.append(
                f"reference.distance_from_speaker_m: {len(given)} distances for "
                f"{self.n_speakers} speakers; write one per speaker, or one value for all")
        wrong = [d for d in distances if not 0 < d <= 0.1]
        if wrong:
            problems.append(f"reference.distance_from_speaker_m: {wrong[0]} m is not within "
                            "0..0.1 m; write the distance in metres (2 mm = 0.002)")
        names = [c.name for c in self.cameras]
        for name in sorted({n for n in names if names.count(n) > 1}):
            problems.append(f"cameras: {name!r} is named twice; write a name of its own for "
                            "each camera")
        for i, camera in enumerate(self.cameras):
            if camera.intrinsics is not None:
                problems += _intrinsics_problems(camera.intrinsics, f"cameras[{i}].intrinsics")
        period = self.burst.period_problem(self.sample_rate_hz, "burst")
        if period is not None:
            problems.append(period)
        if isinstance(self.layout, KnownLayout):  # an import's is checked when it is read
            problems += layout_problems(self.layout.mic_ids, len(self.layout.positions_m),
                                        list(mic_ids))
        return problems

    # -- what calibration asks of it ----------------------------------------------------------

    @property
    def n_speakers(self) -> int:
        return len(self.rig.speakers_m)

    def reference_distances_m(self) -> tuple[float, ...]:
        """The reference microphone's distance from each speaker, in speaker order."""
        d = self.reference.distance_from_speaker_m
        return tuple(d) if isinstance(d, tuple) else (float(d),) * self.n_speakers

    @property
    def reference_on_poses(self) -> bool:
        """True when the pose recordings hold the reference microphone on its stand."""
        return self.reference.pose_recordings_column is not None

    def microphones(self) -> list[tuple[int, int, str]]:
        """(mic id, column, group) of every microphone, in column order."""
        return sorted(((m, c, g.group) for g in self.channels
                       for c, m in zip(g.columns, g.mic_ids, strict=True)),
                      key=lambda entry: entry[1])


def _intrinsics_problems(known: KnownIntrinsics, where: str) -> list[str]:
    K = known.camera_matrix
    problems = []
    if not (K[0][0] > 0 and K[1][1] > 0 and K[2] == (0.0, 0.0, 1.0) and K[1][0] == 0
            and K[0][1] == 0):
        problems.append(f"{where}.camera_matrix: {[list(r) for r in K]} is not a pinhole "
                        "matrix; write [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    if known.use == "prior" and known.std is None:
        problems.append(f"{where}.std: a prior needs its standard deviations; write std = "
                        "[fx, fy, cx, cy, k1, k2, p1, p2, k3] (px and unitless), or use = "
                        "'fixed'")
    if known.std is not None and any(s <= 0 for s in known.std):
        problems.append(f"{where}.std: every standard deviation must be > 0 (got "
                        f"{list(known.std)}); write a small value for a well-known one, or "
                        "use = 'fixed'")
    return problems


def validate_description(document: dict, source: str = "the description") -> RigArrayDescription:
    """A rig and array description from a parsed document (TOML or JSON).

    Raises:
        DescriptionError: naming `source` then one line per problem.
    """
    try:
        return RigArrayDescription.model_validate(document)
    except ValidationError as exc:
        raise DescriptionError(problem_text(source, exc, RigArrayDescription)) from None


def problem_text(source: str, exc: ValidationError, root: type[ConfigModel]) -> str:
    """`source is invalid:` then one indented line per problem (multi-line problems of the
    cross-field checks split into their own lines)."""
    lines = []
    errors = exc.errors()
    for error, line in zip(errors, describe_problems(exc, root), strict=True):
        loc = tuple(error["loc"])
        if error["type"] == "too_short" and any(
                tuple(e["loc"])[:len(loc)] == loc and len(e["loc"]) > len(loc) for e in errors):
            continue  # pydantic's echo of an item refused above: the list is not too short
        _, _, rest = line.partition(": ")
        if _NAMES_ITS_FIELD.match(rest):
            lines += rest.split("\n")  # the cross-field checks name their own fields
        else:
            lines.append(line)
    return f"{source} is invalid:\n" + "".join(f"  {ln}\n" for ln in lines)
