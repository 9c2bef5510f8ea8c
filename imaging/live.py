"""Live acoustic maps: a stream of microphone samples in, a map per video frame out.

Everything that does not change while the view runs is computed once, when the `LiveImager`
is made: the scan grid (the plane z = depth of the chosen camera's frame over its field of
view, `view_plane.depth_plane_grid`), the band's DFT bins, the steering vectors of the grid at
the band centre (complex64 for delay-and-sum, complex128 for CLEAN-SC, see `cleansc`), their
|h|^2, and the pixel table of the camera (`overlay.ImageMapper`). Per frame there remain:
the new Welch blocks' spectra (`sliding_csm`), the band CSM of the latest window (the sum of
its bins' matrices, the paper's band CSM of section VI), and one beamforming pass
(`beamform.beamform_csm`, the Cholesky form, on threads), or CLEAN-SC on it
(`cleansc.clean_sc`, stopped at the map's dynamic range and at `max_components`: what lies
below the range is not drawn anyway).

The map of a band is the band CSM beamformed at the band's centre frequency, as in
`recording_map` (`micam image`): for a third octave this broadens the beam a little compared
with summing a map per bin, which would cost ten times as much per frame; the peak stays on
the source.

Geometry: the calibration result's microphones, speed of sound and channel latencies; when
the result has per-microphone responses, the spectra are corrected for them and the steering
uses the board latencies only (`ArrayGeometry.without_own_delays`), as `micam image` does.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import cv2
import numpy as np

from calibration._blas import single_threaded_blas
from calibration.errors import CalibrationInputError

from .beamform import beamform_csm
from .cleansc import CleanScOptions, clean_sc
from .csm import WelchOptions, band_bins
from .geometry import ArrayGeometry, CameraView
from .grid import PlaneGrid
from .overlay import ImageMapper
from .peaks import subgrid_peak
from .sliding_csm import SlidingCsm
from .steering import Formulation, SteeringModel
from .view_plane import depth_plane_grid

FRACTIONS = (1, 3)
"""Band widths a live view offers: octave and third-octave."""


@dataclass(frozen=True)
class LiveSettings:
    """What the live view computes.

    Attributes:
        band_hz: band centre frequency, hertz.
        fraction: 1 (octave) or 3 (third octave).
        block_size: Welch block length N, samples.
        overlap: Welch block overlap, 0 <= overlap < 1.
        window_s: the CSM's averaging window (whole blocks, at least one), seconds.
        depth_m: the scan plane's distance in front of the camera (its z), metres.
        grid_shape: scan points (n_u along the image's x, n_v along its y).
        camera: the camera the map is drawn on.
        clean_sc: deconvolve with CLEAN-SC instead of drawing the delay-and-sum map.
        dynamic_range_db: the map is drawn down to this many dB below its peak.
        max_components: CLEAN-SC components per frame at most.
        formulation: steering vectors (see `steering`).
        image_scale: the drawn image's size relative to the camera's.
        workers: threads for beamforming (None: all cores).
    """

    band_hz: float = 4000.0
    fraction: int = 3
    block_size: int = 1024
    overlap: float = 0.5
    window_s: float = 0.1
    depth_m: float = 1.0
    grid_shape: tuple[int, int] = (101, 101)
    camera: str = "cam0"
    clean_sc: bool = False
    dynamic_range_db: float = 15.0
    max_components: int = 30
    formulation: Formulation = Formulation.TRUE_LOCATION
    image_scale: float = 1.0
    workers: int | None = None

    def __post_init__(self) -> None:
        if self.fraction not in FRACTIONS:
            raise CalibrationInputError(f"a live band is an octave (1) or a third octave (3), not "
                                        f"1/{self.fraction}")
        if not self.window_s > 0 or not self.dynamic_range_db > 0:
            raise CalibrationInputError("the CSM window and the dynamic range must be positive")
        if self.max_components < 1:
            raise CalibrationInputError(f"max_components {self.max_components} must be at least 1")
        object.__setattr__(self, "formulation", Formulation(self.formulation))

    @property
    def welch(self) -> WelchOptions:
        return WelchOptions(self.block_size, self.overlap)

    def n_blocks(self, sample_rate_hz: float) -> int:
        """Whole blocks in the averaging window (at least 1)."""
        window = round(self.window_s * sample_rate_hz)
        return max(1, self.welch.n_blocks(window))


@dataclass(frozen=True)
class LiveMap:
    """One frame's map.

    Attributes:
        values: (n_u, n_v) map power (the band's, units of the input squared).
        peak_index: fractional grid index (i, j) of the peak (sub-grid).
        peak_m: the peak's point, camera-0 frame, metres.
        peak_px: its pixel in the camera's image (full resolution).
        end_sample: stream index one past the window's newest sample.
        window_samples: the samples the window covers (its centre is end - window / 2).
        n_components: CLEAN-SC components (0 for delay-and-sum).
    """

    values: np.ndarray
    peak_index: tuple[float, float]
    peak_m: np.ndarray
    peak_px: np.ndarray
    end_sample: int
    window_samples: int
    n_components: int

    def level_db(self, dynamic_range_db: float) -> np.ndarray:
        """(n_u, n_v) level in dB re the peak, NaN below -dynamic_range_db."""
        peak = float(np.max(self.values))
        if not peak > 0:
            return np.full(self.values.shape, np.nan)
        with np.errstate(divide="ignore"):
            db = 10.0 * np.log10(np.maximum(self.values, 0.0) / peak)
        db[db < -dynamic_range_db] = np.nan
        return db


class LiveImager:
    """Maps of a live stream of the array's microphones (module docstring).

    Args:
        geometry: the calibration result (microphones in its order: the stream's columns).
        settings: band, window, plane, method.
        sample_rate_hz: of the stream.
    """

    def __init__(self, geometry: ArrayGeometry, settings: LiveSettings,
                 sample_rate_hz: float) -> None:
        self.settings = settings
        self.sample_rate_hz = float(sample_rate_hz)
        self.camera: CameraView = geometry.camera(settings.camera)
        responses = geometry.responses
        if responses is not None:
            geometry = geometry.without_own_delays()
        self.n_mics = geometry.n_mics
        bins = band_bins(settings.band_hz, settings.fraction, settings.block_size,
                         sample_rate_hz)
        self.csm = SlidingCsm(self.n_mics, sample_rate_hz, bins, settings.welch,
                              settings.n_blocks(sample_rate_hz), responses)
        self.grid: PlaneGrid = depth_plane_grid(self.camera, settings.depth_m,
                                                settings.grid_shape)
        steering = SteeringModel(self.grid.points, geometry.mic_positions_m,
                                 geometry.speed_of_sound_m_s, settings.formulation,
                                 latencies_s=geometry.mic_latencies_s)
        h = steering.vectors(settings.band_hz)
        self._power = np.ascontiguousarray(steering.amplitude**2)
        self._h_das = np.ascontiguousarray(h, dtype=np.complex64)
        self._h_clean = h if settings.clean_sc else None
        self.mapper = ImageMapper(self.grid, self.camera, settings.image_scale)
        self._clean = CleanScOptions(max_iterations=settings.max_components,
                                     min_peak_db=settings.dynamic_range_db)

    def with_range(self, dynamic_range_db: float) -> LiveImager:
        """This imager drawing down to another dynamic range: it shares the CSM, steering and
        pixel table (nothing is set up again, the window goes on); checked as LiveSettings."""
        other = copy.copy(self)
        other.settings = replace(self.settings, dynamic_range_db=dynamic_range_db)
        other._clean = CleanScOptions(max_iterations=self.settings.max_components,
                                      min_peak_db=dynamic_range_db)
        return other

    def push(self, samples: np.ndarray) -> int:
        """Append microphone samples (n, M) (volts or pascals, columns in the geometry's
        microphone order); returns the Welch blocks completed."""
        return self.csm.push(samples)

    @property
    def ready(self) -> bool:
        """True once a whole averaging window has arrived."""
        return self.csm.ready

    def map(self) -> LiveMap:
        """The map of the latest window (delay-and-sum or CLEAN-SC, as set)."""
        with single_threaded_blas():  # small factorisations: see calibration._blas
            return self._map()

    def _map(self) -> LiveMap:
        csm = self.csm.band_csm()
        shape = self.grid.shape
        if self._h_clean is None:
            values = np.maximum(beamform_csm(self._h_das, csm, True, self._power, "single",
                                             self.settings.workers), 0.0)
            peak = subgrid_peak(values, shape)
            n_components = 0
        else:
            result = clean_sc(csm, self._h_clean, self._clean, self._power, shape,
                              workers=self.settings.workers)
            values = _clean_beam(result.clean_map.reshape(shape))
            strongest = max(result.components, key=lambda c: c.power, default=None)
            peak = (strongest.subgrid if strongest is not None and strongest.subgrid
                    is not None else subgrid_peak(values, shape))
            n_components = result.n_iterations
        point = self.grid.at_index(*peak)
        return LiveMap(values.reshape(shape), (float(peak[0]), float(peak[1])), point,
                       self.camera.project(point)[0], self.csm.last_block_end,
                       self.csm.window_samples, n_components)

    def level_image(self, live_map: LiveMap) -> np.ndarray:
        """The map's level in dB re its peak at every pixel of the drawn image (NaN outside
        the dynamic range or the grid)."""
        return self.mapper.to_image(live_map.level_db(self.settings.dynamic_range_db))


CLEAN_BEAM_CELLS = 2.5
"""Standard deviation, in grid cells, of the Gaussian beam CLEAN-SC's point components are
drawn with (a clean map of single nodes would be invisible on a camera image)."""


def _clean_beam(clean: np.ndarray) -> np.ndarray:
    """The clean map (n_u, n_v) convolved with the clean beam, its peaks kept at their
    values."""
    blurred = cv2.GaussianBlur(clean.astype(np.float64), (0, 0), CLEAN_BEAM_CELLS)
    top = float(blurred.max())
    return blurred * (float(clean.max()) / top) if top > 0 else blurred
