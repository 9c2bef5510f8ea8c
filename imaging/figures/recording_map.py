"""The maps of one recording drawn on a camera's image of its pose: what `micam image` makes.

The recording's band CSM (with the settings' simulated error and correction, see
`evaluate.bin_spectra`) is beamformed on the rig plane through the speakers over all that the
camera sees of it (`overlay.field_of_view_grid`) and deconvolved by CLEAN-SC; the
delay-and-sum map and the CLEAN-SC point sources are drawn over the image
(`figures.maps.acoustic_map_figure`), with the speakers where the geometry (the camera) places
them and a scale bar of the image's scale at the playing speaker (`pixels_per_metre`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from acquisition.contracts.session import SessionReader
from acquisition.contracts.step_ids import pose_step
from calibration.errors import CalibrationInputError
from calibration.figures.maps import MapPanel, ScaleBar, acoustic_map_figure

from ..beamform import beamform_csm
from ..cleansc import CleanScOptions, clean_sc
from ..evaluate import ImagingSettings, bin_spectra, geometry_steering, mic_signals
from ..geometry import ArrayGeometry, CameraView
from ..grid import PlaneGrid
from ..overlay import clean_sources, field_of_view_grid, map_to_image
from ..steering import Formulation


@dataclass(frozen=True)
class RecordingMap:
    """The figure and what it found.

    Attributes:
        figure: the two panels (delay-and-sum, CLEAN-SC) over the camera's image.
        speakers_px: (n, 2) the speakers' pixels in the camera's image.
        sources_px: (K, 2) the CLEAN-SC point sources' pixels, strongest first.
        error_m: the strongest CLEAN-SC point's (sub-grid) distance from the speaker.
        node_error_m: the distance of its grid node from the speaker.
        spacing_m: the grid spacing used.
        n_components: CLEAN-SC components.
        speaker_in_view: whether the camera sees the imaged speaker (outside its view, the map
            covers only what it sees, and its peak cannot be at the speaker).
    """

    figure: Figure
    speakers_px: np.ndarray
    sources_px: np.ndarray
    error_m: float
    node_error_m: float
    spacing_m: float
    n_components: int
    speaker_in_view: bool


def pixels_per_metre(view: CameraView, grid: PlaneGrid, at_m: np.ndarray,
                     step_m: float = 0.01) -> float:
    """The camera's image scale on the grid's plane at `at_m` (camera-0 frame): the square
    root of the image area (pixels^2) of a small square of the plane over its area (m^2): the
    geometric mean of the scales along the plane's two directions, which perspective makes
    differ."""
    px = view.project(np.array([at_m, at_m + step_m * grid.u_axis, at_m + step_m * grid.v_axis]))
    a, b = px[1] - px[0], px[2] - px[0]
    return float(np.sqrt(abs(a[0] * b[1] - a[1] * b[0])) / step_m)


def recording_map(reader: SessionReader, geometry: ArrayGeometry, pose: int, speaker: int,
                  band_hz: float, settings: ImagingSettings, camera: str = "cam0",
                  spacing_m: float = 0.004, dynamic_range_db: float = 15.0,
                  formulation: Formulation | str = Formulation.TRUE_LOCATION) -> RecordingMap:
    """The maps of `speaker`'s recording at `pose` in the band around band_hz (module
    docstring). Raises ValueError (or SessionError) naming what is missing or wrong."""
    step = pose_step(pose)
    board = geometry.pose(pose)
    view = geometry.camera(camera)
    if not 0 <= speaker < len(board.speakers_m):
        raise CalibrationInputError(
            f"the rig has speakers 0-{len(board.speakers_m) - 1}, not {speaker}")
    signals, fs = mic_signals(reader, step, f"speaker_{speaker}.wav", geometry)
    image = reader.read_image(step, f"{camera}.png")
    band = bin_spectra(signals, fs, settings).band_sum(band_hz, settings.fraction)
    rig_z = float(np.mean(np.asarray(reader.capture["rig"]["speakers_m"])[:, 2]))
    grid = field_of_view_grid(view, board, rig_z, spacing_m)
    steering = geometry_steering(geometry, grid.points, formulation)
    h = steering.vectors(band_hz)
    power = steering.amplitude**2
    das = np.maximum(beamform_csm(h, band.csm[0], True, power), 0.0)
    clean = clean_sc(band.csm[0], h, CleanScOptions(), power, grid.shape)
    points, powers = clean_sources(clean, grid)
    spacing = grid.spacing()[0]
    title = (f"{step} speaker {speaker}, {band_hz:.0f} Hz 1/{settings.fraction} octave, "
             f"{1e3 * spacing:.1f} mm grid")
    notes = []
    if settings.simulated_error is not None:
        notes.append(settings.simulated_error.source)
    if settings.correction is not None:
        notes.append(f"CSM corrected by the {settings.correction.source}")
    speakers_px = view.project(board.speakers_m)
    sources_px = view.project(points)
    figure = acoustic_map_figure(
        image, [MapPanel("delay-and-sum", map_to_image(das, grid, view)),
                MapPanel(f"CLEAN-SC: {len(clean.components)} components at {len(points)} "
                         f"point{'s' if len(points) > 1 else ''}", None, sources_px, powers)],
        speakers_px, speaker, dynamic_range_db, "\n".join([title, "; ".join(notes)]
                                                           if notes else [title]),
        ScaleBar(pixels_per_metre(view, grid, board.speakers_m[speaker]),
                 "at the playing speaker"))
    node = int(np.argmax(clean.clean_map))
    target = board.speakers_m[speaker]
    return RecordingMap(figure, speakers_px, sources_px,
                        float(np.linalg.norm(points[0] - target)),
                        float(np.linalg.norm(grid.points[node] - target)), spacing,
                        len(clean.components), bool(view.sees(target[None, :])[0]))
