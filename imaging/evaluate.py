"""Localization evaluation of a session (paper VI-A) and the per-recording imaging it needs.

For every recording of a pose step (one speaker playing), the cross-spectral matrix is summed
into 1/fraction-octave bands (the paper: 1/12 octave, 5-15 kHz), each band is beamformed at its
centre frequency on the rig's surface through the speakers (`PlaneGrid.on_rig` at the rig's
Z = speaker depth, from the board pose of the geometry file), deconvolved by CLEAN-SC, and the
CLEAN-SC peak is compared with the speaker's position: eq. 21, eps = |X_s - xi_max|.

The CLEAN-SC peak is the grid node with the most clean-map power; its position to a fraction
of the grid spacing is the sub-grid peak (`peaks.subgrid_peak`) of the dirty map the strongest
component at that node was taken from. Both the node error (the paper's measure, quantised
by the grid: about 0.38 x spacing whatever the band) and the sub-grid error are kept; with a
simulated session's truth, the error against the true speaker position too (the camera's own
error taken out).

Recordings are classed by the distance of the rig's pattern centre from camera 0, the distance
`micam simulate --distance` draws. The channels' responses can be corrected in the CSM before
beamforming (`ImagingSettings.correction`, see `csm_calibration`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from itertools import pairwise
from pathlib import Path

import numpy as np

from acquisition.contracts.session import SessionReader
from acquisition.contracts.step_ids import pose_index, pose_step
from calibration._cores import resolve_workers
from calibration.errors import CalibrationInputError

from .cleansc import LOCKSTEP_BINS, CleanScOptions, clean_sc_many
from .csm import CrossSpectra, WelchOptions, band_bins, cross_spectra, octave_band_centres
from .csm_calibration import ChannelResponses, apply_responses, correct_csm, eigen_calibration
from .geometry import ArrayGeometry, BoardPose
from .grid import PlaneGrid
from .parallel import Mapper, run_in_processes
from .steering import Formulation, SteeringModel

DISTANCE_BINS_M = (0.0, 0.6, 1.0, 1.5, 2.0, 3.0, np.inf)
"""Edges of the distance classes of the summary: the distance of the rig's pattern centre from
camera 0, as `micam simulate --distance` draws it."""


@dataclass(frozen=True)
class ImagingSettings:
    """How each recording is imaged.

    Attributes:
        welch: CSM block length, overlap and window (the paper: 4096, 50 %, Hann).
        fraction: bands are 1/fraction octave wide (the paper: 12).
        band_lo_hz, band_hi_hz: band centres within this range are evaluated.
        spacing_m: grid spacing on the rig plane (the paper: 6 mm).
        margin_m: how far the grid extends beyond the outermost speakers, on the rig.
        formulation: steering vectors.
        clean: CLEAN-SC options (default: stop 20 dB below the first peak, since only the
            strongest source of each single-speaker recording is evaluated).
        offset_seed: the grid of each pose is shifted by a random fraction of a cell along each
            rig axis (seeded by this and the pose), so that the speakers fall anywhere within a
            cell as on an arbitrary grid; None aligns the grid with the speakers' rig
            coordinates (the paper's speakers then sit on nodes of a 6 mm grid).
        bands_hz: explicit band centres instead of the nominal ones between band_lo_hz and
            band_hi_hz (e.g. the one band of `micam image`).
        correction: channel responses the CSM is corrected for before beamforming
            (`csm_calibration.correct_csm`, per DFT bin), or None.
        simulated_error: channel responses applied to every recording's spectra first
            (`csm_calibration.apply_responses`): a microphone error of a chosen size simulated
            in the evaluation (the world's own capsule responses are in the recordings).
    """

    welch: WelchOptions = field(default_factory=WelchOptions)
    fraction: int = 12
    band_lo_hz: float = 5000.0
    band_hi_hz: float = 15000.0
    spacing_m: float = 0.006
    margin_m: float = 0.06
    formulation: Formulation = Formulation.TRUE_LOCATION
    clean: CleanScOptions = field(default_factory=lambda: CleanScOptions(min_peak_db=20.0))
    offset_seed: int | None = 0
    bands_hz: tuple[float, ...] | None = None
    correction: ChannelResponses | None = None
    simulated_error: ChannelResponses | None = None

    def grid_shift(self, pose: int) -> tuple[float, float]:
        """The pose's grid shift in cells (see `offset_seed`)."""
        if self.offset_seed is None:
            return 0.0, 0.0
        a, b = np.random.default_rng([self.offset_seed, pose]).uniform(0.0, 1.0, 2)
        return float(a), float(b)

    def band_centres(self) -> np.ndarray:
        if self.bands_hz is not None:
            return np.asarray(self.bands_hz, dtype=np.float64)
        return octave_band_centres(self.band_lo_hz, self.band_hi_hz, self.fraction)


def mic_signals(reader: SessionReader, step: str, name: str, geometry: ArrayGeometry
                ) -> tuple[np.ndarray, float]:
    """A recording's microphone columns in volts (n_samples, M), in the geometry's microphone
    order, and the sample rate. Volts = code * range_v / 32768 per column."""
    codes, fs = reader.read_recording(step, name)
    columns = reader.capture["columns"]
    by_id = {c["mic_id"]: j for j, c in enumerate(columns) if c["role"] == "mic"}
    missing = [m for m in geometry.mic_ids if m not in by_id]
    if missing:
        raise CalibrationInputError(
            f"the geometry's microphones {missing[:5]} are not recorded in this "
            "session; use the geometry calibrated for this array")
    cols = [by_id[m] for m in geometry.mic_ids]
    scale = np.array([columns[j]["range_v"] / 32768.0 for j in cols])
    return codes[:, cols].astype(np.float64) * scale, float(fs)


def pattern_centre_rig(capture: dict) -> np.ndarray:
    """The centre of the checkerboard's inner corners in the rig frame (metres), from a
    session's capture configuration (its "rig": corners_x, corners_y, square_m)."""
    rig = capture["rig"]
    return np.array([(rig["corners_x"] - 1) * rig["square_m"] / 2,
                     (rig["corners_y"] - 1) * rig["square_m"] / 2, 0.0])


def pose_distance(pose: BoardPose, capture: dict) -> float:
    """Distance (m) of the rig's pattern centre from camera 0 at a pose: the distance
    `micam simulate --distance` draws."""
    return float(np.linalg.norm(pose.rig_to_cam0.apply(pattern_centre_rig(capture))))


def rig_grid(pose: BoardPose, rig_speakers_m: np.ndarray, spacing_m: float, margin_m: float,
             shift_cells: tuple[float, float] = (0.0, 0.0)) -> PlaneGrid:
    """The rig plane through the speakers (their rig Z), covering them with a margin; its
    nodes are shifted by shift_cells grid cells along the rig's X and Y."""
    rig = np.asarray(rig_speakers_m, dtype=np.float64)
    shift = spacing_m * np.asarray(shift_cells, dtype=np.float64)
    lo = rig[:, :2].min(axis=0) - margin_m - shift
    hi = rig[:, :2].max(axis=0) + margin_m
    return PlaneGrid.on_rig(pose.rig_to_cam0, (lo[0], hi[0]), (lo[1], hi[1]),
                            float(rig[:, 2].mean()), spacing_m)


def geometry_steering(geometry: ArrayGeometry, points: np.ndarray,
                      formulation: Formulation | str) -> SteeringModel:
    """The steering model of an array geometry (positions, c and channel latencies)."""
    return SteeringModel(points, geometry.mic_positions_m, geometry.speed_of_sound_m_s,
                         formulation, latencies_s=geometry.mic_latencies_s)


@dataclass(frozen=True)
class BandLocation:
    """The CLEAN-SC peak of one band: its grid node and sub-grid position (camera-0 frame),
    its clean-map power, and the dirty (delay-and-sum) map's peak, the first component's."""

    band_hz: float
    node_m: np.ndarray
    subgrid_m: np.ndarray
    power: float
    dirty_peak: float


def bin_spectra(signals: np.ndarray, fs: float, settings: ImagingSettings) -> CrossSpectra:
    """The DFT-bin CSMs of a recording over the bands of the settings, with the settings'
    simulated channel error applied and their correction made."""
    n = settings.welch.block_size
    bins = np.unique(np.concatenate([band_bins(f, settings.fraction, n, fs)
                                     for f in settings.band_centres()]))
    spectra = cross_spectra(signals, fs, bins, settings.welch)
    if settings.simulated_error is not None:
        spectra = apply_responses(spectra, settings.simulated_error)
    if settings.correction is not None:
        spectra = correct_csm(spectra, settings.correction)
    return spectra


def band_spectra(signals: np.ndarray, fs: float, settings: ImagingSettings
                 ) -> list[CrossSpectra]:
    """The band-summed CSMs of a recording, one per band centre of the settings."""
    spectra = bin_spectra(signals, fs, settings)
    return [spectra.band_sum(f, settings.fraction) for f in settings.band_centres()]


def channel_calibration(reader: SessionReader, geometry: ArrayGeometry, pose: int,
                        speaker: int, settings: ImagingSettings) -> ChannelResponses:
    """Dougherty's eigenvalue calibration (`csm_calibration.eigen_calibration`) of the
    channels in every band of the settings, from the recording of `speaker` at `pose`, whose
    position is the geometry's (the camera's). The settings' simulated error is applied to
    the recording; their correction is not."""
    step = pose_step(pose)
    name = f"speaker_{speaker}.wav"
    board = geometry.pose(pose)
    if not 0 <= speaker < len(board.speakers_m):
        raise CalibrationInputError(
            f"the rig has speakers 0-{len(board.speakers_m) - 1}, not {speaker}")
    signals, fs = mic_signals(reader, step, name, geometry)
    spectra = bin_spectra(signals, fs, replace(settings, correction=None))
    model = geometry_steering(geometry, board.speakers_m[speaker][None], Formulation.CLASSIC)
    transfer = np.array([model.vectors(f)[0] for f in spectra.freqs_hz])
    transfer /= model.distances[0]  # the 1/r_m of a monopole (CLASSIC has none)
    return eigen_calibration(spectra, transfer, settings.band_centres(), settings.fraction,
                             f"eigenvalue calibration from {step} speaker {speaker}")


def locate(spectra: Iterable[CrossSpectra], steering: SteeringModel, grid: PlaneGrid,
           options: CleanScOptions, vectors: dict[float, np.ndarray] | None = None
           ) -> list[BandLocation]:
    """The CLEAN-SC peak of each band-summed CSM on `grid` (the bands iterated together in
    groups of `LOCKSTEP_BINS`, see `clean_sc_many`).

    `vectors`: steering vectors by band centre (Hz), filled as they are computed, to be
    passed again for other recordings on the same grid.
    """
    vectors = {} if vectors is None else vectors

    def steering_at(freq_hz: float) -> np.ndarray:
        if freq_hz not in vectors:
            vectors[freq_hz] = steering.vectors(freq_hz)
        return vectors[freq_hz]

    power = steering.amplitude**2
    bands = list(spectra)
    out = []
    for start in range(0, len(bands), LOCKSTEP_BINS):
        group = bands[start:start + LOCKSTEP_BINS]
        results = clean_sc_many(np.array([band.csm[0] for band in group]),
                                (steering_at(float(band.freqs_hz[0])) for band in group),
                                power, options, grid.shape)
        for band, result in zip(group, results, strict=True):
            if not result.components:
                continue
            node = int(np.argmax(result.clean_map))
            strongest = max((c for c in result.components if c.index == node),
                            key=lambda c: c.power)
            sub = strongest.subgrid  # None only off a 2-D grid: the node itself then
            out.append(BandLocation(float(band.freqs_hz[0]), grid.points[node],
                                    grid.at_index(*sub) if sub is not None else grid.points[node],
                                    float(result.clean_map[node]),
                                    float(result.components[0].peak)))
    return out


@dataclass(frozen=True)
class Localization:
    """One evaluated (recording, band): eq. 21 at the grid node and at the sub-grid peak.

    Attributes:
        distance_m: of the rig's pattern centre from camera 0 (`pose_distance`).
        error_node_m, error_m: the grid node's and the sub-grid peak's distance from the
            speaker as the geometry (the camera) places it.
        error_truth_m: the sub-grid peak's distance from the true speaker position (simulated
            sessions evaluated with their truth), else None.
        dirty_peak: the delay-and-sum map's peak (the first CLEAN-SC component's), in the
            CSM's units: compared between evaluations of the same recordings, its ratio says
            how much of the source's coherent power the map recovers.
    """

    pose: int
    speaker: int
    distance_m: float
    band_hz: float
    error_node_m: float
    error_m: float
    error_truth_m: float | None = None
    dirty_peak: float = float("nan")


@dataclass(frozen=True)
class Summary:
    """Error statistics of a set of localizations, in metres (truth_mean_m: None without a
    truth)."""

    count: int
    mean_m: float
    median_m: float
    p95_m: float
    mean_node_m: float
    truth_mean_m: float | None = None

    @staticmethod
    def of(rows: list[Localization]) -> Summary:
        e = np.array([r.error_m for r in rows])
        node = np.array([r.error_node_m for r in rows])
        truth = [r.error_truth_m for r in rows if r.error_truth_m is not None]
        return Summary(len(rows), float(e.mean()), float(np.median(e)),
                       float(np.percentile(e, 95)), float(node.mean()),
                       float(np.mean(truth)) if len(truth) == len(rows) else None)

    def to_json(self) -> dict:
        out = {"count": self.count, "mean_mm": 1e3 * self.mean_m,
               "median_mm": 1e3 * self.median_m, "p95_mm": 1e3 * self.p95_m,
               "mean_node_mm": 1e3 * self.mean_node_m}
        if self.truth_mean_m is not None:
            out["truth_mean_mm"] = 1e3 * self.truth_mean_m
        return out


@dataclass(frozen=True)
class Evaluation:
    """All localizations of a session with their summaries."""

    rows: list[Localization]
    settings: ImagingSettings

    def overall(self) -> Summary:
        if not self.rows:
            raise CalibrationInputError("no recording was evaluated")
        return Summary.of(self.rows)

    def by_band(self) -> dict[float, Summary]:
        bands = sorted({r.band_hz for r in self.rows})
        return {b: Summary.of([r for r in self.rows if r.band_hz == b]) for b in bands}

    def by_distance(self) -> dict[tuple[float, float], Summary]:
        out = {}
        for lo, hi in pairwise(DISTANCE_BINS_M):
            rows = [r for r in self.rows if lo <= r.distance_m < hi]
            if rows:
                out[(lo, hi)] = Summary.of(rows)
        return out

    def to_json(self) -> dict:
        s = self.settings
        return {
            "settings": {"block_size": s.welch.block_size, "overlap": s.welch.overlap,
                         "window": s.welch.window, "fraction": s.fraction,
                         "band_lo_hz": s.band_lo_hz, "band_hi_hz": s.band_hi_hz,
                         "spacing_mm": 1e3 * s.spacing_m, "formulation": str(s.formulation),
                         "loop_gain": s.clean.loop_gain, "min_peak_db": s.clean.min_peak_db,
                         "grid_offset_seed": s.offset_seed,
                         "correction": None if s.correction is None else s.correction.source,
                         "simulated_error": (None if s.simulated_error is None
                                             else s.simulated_error.source)},
            "distance_classes": "distance of the rig's pattern centre from camera 0, m",
            "overall": self.overall().to_json(),
            "by_band": [{"band_hz": b, **v.to_json()} for b, v in self.by_band().items()],
            "by_distance": [{"from_m": lo, "to_m": hi if np.isfinite(hi) else None,
                             **v.to_json()} for (lo, hi), v in self.by_distance().items()],
        }


Recording = tuple[str, str, int]
"""(step, file name, speaker index) of one speaker recording."""


def _evaluate_pose(reader: SessionReader, geometry: ArrayGeometry, settings: ImagingSettings,
                   pose: int, recordings: list[Recording], true_speakers: np.ndarray | None
                   ) -> list[Localization]:
    """The localizations of one pose's recordings (one grid and steering model for all);
    true_speakers (n_speakers, 3): the truth's positions of the pose's speakers, or None."""
    rig_speakers = np.asarray(reader.capture["rig"]["speakers_m"], dtype=np.float64)
    board = geometry.pose(pose)
    distance = pose_distance(board, reader.capture)
    grid = rig_grid(board, rig_speakers, settings.spacing_m, settings.margin_m,
                    settings.grid_shift(pose))
    steering = geometry_steering(geometry, grid.points, settings.formulation)
    vectors: dict[float, np.ndarray] = {}  # by band, shared by the pose's recordings
    rows = []
    for step, name, speaker in recordings:
        signals, fs = mic_signals(reader, step, name, geometry)
        located = board.speakers_m[speaker]
        for loc in locate(band_spectra(signals, fs, settings), steering, grid, settings.clean,
                          vectors):
            rows.append(Localization(
                pose, speaker, distance, loc.band_hz,
                float(np.linalg.norm(loc.node_m - located)),
                float(np.linalg.norm(loc.subgrid_m - located)),
                None if true_speakers is None
                else float(np.linalg.norm(loc.subgrid_m - true_speakers[speaker])),
                loc.dirty_peak))
    return rows


def _evaluate_pose_in_worker(session: Path, geometry: ArrayGeometry, settings: ImagingSettings,
                             pose: int, recordings: list[Recording],
                             true_speakers: np.ndarray | None) -> list[Localization]:
    """`_evaluate_pose` in a worker process, which opens the session itself."""
    return _evaluate_pose(SessionReader(session), geometry, settings, pose, recordings,
                          true_speakers)


def session_recordings(reader: SessionReader) -> dict[int, list[Recording]]:
    """The speaker recordings of every completed pose step, by pose number."""
    by_pose: dict[int, list[Recording]] = {}
    for step, record in sorted(reader.steps().items()):
        pose = pose_index(step)
        if pose is None:
            continue
        for name, file in sorted(record.files.items()):
            if file.role == "recording" and "speaker" in file.meta:
                by_pose.setdefault(pose, []).append((step, name, int(file.meta["speaker"])))
    return by_pose


def evaluate_session(reader: SessionReader, geometry: ArrayGeometry,
                     settings: ImagingSettings | None = None,
                     progress: Callable[[int, int], None] | None = None,
                     workers: int | None = 1, poses: Iterable[int] | None = None,
                     skip: Iterable[tuple[int, int]] = (),
                     truth: ArrayGeometry | None = None,
                     mapper: Mapper | None = None) -> Evaluation:
    """Localize every speaker recording of every completed pose step (paper VI-A).

    Args:
        progress: called with (done, total) recordings after each pose.
        workers: processes the poses are shared over (None: all cores; 1: this process; see
            `parallel.run_in_processes`, and `clean_sc_spectra` for what a script calling it
            with more than 1 must do).
        poses: evaluate only these pose numbers (default: every pose recorded).
        skip: (pose, speaker) recordings left out (e.g. the one the channels were calibrated
            from, which would score itself).
        truth: a simulated session's truth: each error is also measured against the true
            speaker positions (`Localization.error_truth_m`).
        mapper: runs the poses elsewhere instead, e.g. on a Dask cluster (`workers` is
            then unused): the same localizations, bit for bit, as here.
    """
    settings = settings or ImagingSettings()
    left_out = set(skip)
    wanted = None if poses is None else set(poses)
    by_pose = {pose: kept for pose, recordings in session_recordings(reader).items()
               if wanted is None or pose in wanted
               if (kept := [r for r in recordings if (pose, r[2]) not in left_out])}
    if not by_pose:
        raise CalibrationInputError(f"{reader.path} has no completed pose recordings to evaluate")
    true_speakers = {pose: None if truth is None else truth.pose(pose).speakers_m
                     for pose in by_pose}
    total = sum(len(r) for r in by_pose.values())
    n_processes = min(resolve_workers(workers), len(by_pose))
    if mapper is None and n_processes > 1:
        mapper = functools.partial(run_in_processes, workers=n_processes)
    if mapper is not None:
        jobs = [(Path(reader.path), geometry, settings, pose, recordings, true_speakers[pose])
                for pose, recordings in by_pose.items()]
        results: Iterable[list[Localization]] = mapper(_evaluate_pose_in_worker, jobs)
    else:
        results = (_evaluate_pose(reader, geometry, settings, pose, recordings,
                                  true_speakers[pose])
                   for pose, recordings in by_pose.items())
    rows: list[Localization] = []
    done = 0
    for recordings, pose_rows in zip(by_pose.values(), results, strict=True):
        rows.extend(pose_rows)
        done += len(recordings)
        if progress is not None:
            progress(done, total)
    return Evaluation(rows, settings)
