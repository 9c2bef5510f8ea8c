"""The realistic lab: the systematic effects that decide a real calibration, each switchable.

The ideal simulated world has point speakers at their stated rig positions, a checkerboard
printed exactly to scale, identical microphones, still air at one temperature and no room.
Real calibrations fail on exactly those idealisations (shared/reference/calibration-math.md,
section G; docs/simulation.md gives each magnitude and where it comes from). `LabEffects`
turns each one on, with the magnitudes of a careful lab; `LabTruth` holds the values drawn for
one world (hidden from the calibration, written to truth.json).

Effects (names as `micam simulate --effect NAME` takes them):

- acoustic-centres: each speaker's far-field acoustic centre lies a few millimetres in front
  of its diaphragm along the board normal, and moves a little with frequency. The reference
  microphone 2 mm from the diaphragm hears the diaphragm; the array (and the reference
  microphone on its stand) hear the acoustic centre.
- rig-tolerance: each speaker's diaphragm sits a few tenths of a millimetre (per axis) off its
  stated rig position.
- print-scale: the printed checkerboard is about 0.1 % larger or smaller than stated.
- mic-responses: every capsule has its own frequency response: a pure delay (electronics,
  anti-alias filters) and a capsule resonance whose frequency varies, i.e. a group delay that
  differs by about half a microsecond between microphones and varies with frequency (the
  sensitivity spread is the world's `NoiseModel.gain_spread_db`).
- air-drift: the air warms or cools by a few tenths of a kelvin over the session.
- room: first-order image sources of a room's floor, ceiling and walls and of a table below
  the array, frequency-independent absorption.
- ambient-noise: low-frequency noise (ventilation, traffic) arriving as plane waves from a few
  directions plus an incoherent part.
- directivity: each speaker radiates as a baffled piston of its stated diameter (off-axis
  roll-off at high frequencies).
- driver-delays: each speaker's driver, amplifier and output sound a little earlier or later
  than the others' (units of one kind differ). Its own reference recording holds the same
  delay, so it cancels, except for a speaker measured on another's reference recording.
- air-sensor: the lab has a calibrated thermometer and hygrometer beside the array, read at
  every pose; each has a fixed calibration error drawn from its stated accuracy.
- the cameras' effects (sim.optics.CAMERA_EFFECTS): sensor-noise, fixed-pattern, defocus,
  lens-distortion, vignetting, lighting, board-bow, gamma.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .errors import SimulationInputError
from .geometry import Rig
from .optics import CAMERA_EFFECTS, CameraEffects

EFFECTS = ("acoustic-centres", "rig-tolerance", "print-scale", "mic-responses", "air-drift",
           "room", "ambient-noise", "directivity", "driver-delays", "air-sensor",
           *CAMERA_EFFECTS)
"""Every effect's name, in the order of docs/simulation.md's tables ("air-sensor" is not an
error but the lab's instrument: a thermometer and hygrometer beside the array; the cameras'
effects last)."""


DRIVER_DELAY_STD_S = 2e-6
"""The driver-delays effect's spread of the speakers' emission delays, seconds: drivers of one
kind differ in their resonance by 10-20 %, which moves their group delay in the band by a few
microseconds; the amplifier channels and outputs of one board differ by far less."""


@dataclass(frozen=True)
class AcousticCentreModel:
    """Where each speaker's sound appears to come from, seen from the far field.

    Attributes:
        offset_range_m: each speaker's offset in front of its diaphragm (along the board
            normal, out of the printed face) at `reference_hz`, drawn uniformly in this range.
        slope_m_per_octave: change of the offset per octave of frequency (the same for all
            speakers; negative: the centre moves towards the diaphragm at high frequencies).
        reference_hz: the frequency at which the offset is `offset_range_m`'s draw.
    """

    offset_range_m: tuple[float, float] = (1.5e-3, 4.0e-3)
    slope_m_per_octave: float = -0.2e-3
    reference_hz: float = 4_000.0


@dataclass(frozen=True)
class MicResponseModel:
    """The spread of the capsules' responses.

    Each microphone's response is exp(-j 2 pi f d) / (1 + j (f / f_r) / q - (f / f_r)^2): a
    delay d ~ N(0, delay_std_s) and a second-order resonance at f_r = resonance_hz (1 + e),
    e ~ N(0, resonance_spread). The resonance's group delay at low frequencies is
    1 / (2 pi f_r q) (6.4 us at 25 kHz, q = 1), so a 5 % spread gives 0.32 us; with the 0.35 us
    delay spread the group delays differ by about 0.5 us RMS between microphones.
    """

    delay_std_s: float = 0.35e-6
    resonance_hz: float = 25_000.0
    resonance_spread: float = 0.05
    q: float = 1.0


@dataclass(frozen=True)
class RoomModel:
    """A rectangular room (camera-0 frame: x right, y down, z forward) and a table below the
    array; first-order image sources only.

    Attributes:
        walls_m: (x_min, x_max, y_min (ceiling), y_max (floor), z_min (behind the array),
            z_max (in front)) of the room's surfaces.
        absorption: energy absorption coefficient of the room's surfaces (pressure reflection
            factor sqrt(1 - absorption)).
        table_y_m: height of the table top (below the array: positive y).
        table_x_m, table_z_m: extent of the table top.
        table_absorption: energy absorption of the table top (a hard surface).
    """

    walls_m: tuple[float, float, float, float, float, float] = (-1.9, 2.3, -1.45, 1.25,
                                                                -1.2, 3.8)
    absorption: float = 0.3
    table_y_m: float = 0.40
    table_x_m: tuple[float, float] = (-0.5, 0.5)
    table_z_m: tuple[float, float] = (-0.4, 0.5)
    table_absorption: float = 0.1

    def planes(self) -> list[tuple[int, float, float]]:
        """(axis, coordinate, pressure reflection factor) of every reflecting plane."""
        r_wall = float(np.sqrt(1.0 - self.absorption))
        planes = [(axis, self.walls_m[2 * axis + side], r_wall)
                  for axis in range(3) for side in range(2)]
        planes.append((1, self.table_y_m, float(np.sqrt(1.0 - self.table_absorption))))
        return planes

    def reflection_point_valid(self, plane: int, points: np.ndarray) -> np.ndarray:
        """Whether reflection points (..., 3) on plane `plane` (index into `planes`) lie on
        the reflecting surface (the table is finite, the room's surfaces are not)."""
        if plane < 6:
            return np.ones(points.shape[:-1], dtype=bool)
        x, z = points[..., 0], points[..., 2]
        return ((x >= self.table_x_m[0]) & (x <= self.table_x_m[1])
                & (z >= self.table_z_m[0]) & (z <= self.table_z_m[1]))


@dataclass(frozen=True)
class AmbientNoiseModel:
    """Low-frequency ambient noise at every microphone.

    Attributes:
        rms_v: RMS voltage of the noise at a microphone (all of it, mostly below corner_hz).
        corner_hz: the noise's spectrum falls as 1 / (1 + (f / corner_hz)^2) (amplitude).
        n_plane_waves: coherent part: plane waves from this many random directions.
        incoherent_fraction: fraction of the noise power that is independent per channel.
    """

    rms_v: float = 0.03
    corner_hz: float = 80.0
    n_plane_waves: int = 3
    incoherent_fraction: float = 0.2


@dataclass(frozen=True)
class AirSensorModel:
    """The lab's air sensor: what it states as its accuracy (1 sigma), and what it is.

    Attributes:
        temperature_std_k: its thermometer's calibration error (fixed for the session) is
            drawn from N(0, this); a calibrated platinum thermometer (1/10 DIN class) is
            good to a few hundredths of a kelvin.
        relative_humidity_std: the hygrometer's (a calibrated capacitive one: about 1 %).
        pressure_std_pa: the barometer's.
        reading_noise_k: the thermometer's reading-to-reading noise.
    """

    temperature_std_k: float = 0.03
    relative_humidity_std: float = 0.01
    pressure_std_pa: float = 100.0
    reading_noise_k: float = 0.005


@dataclass(frozen=True)
class LabEffects:
    """Which systematic effects the simulated lab has, and how large they are.

    Attributes:
        acoustic_centres: speaker acoustic centres off the diaphragm (None: points at the
            diaphragm).
        rig_tolerance_m: standard deviation, per axis, of each speaker's diaphragm about its
            stated rig position.
        print_scale_range: the printed pattern's relative scale error, drawn uniformly in this
            range with a random sign ((0, 0): printed to scale).
        mic_responses: capsule responses (None: every microphone flat, gain only).
        temperature_drift_k: the air's total temperature change over the session (its sign is
            drawn), plus a slow wander of a tenth of it.
        room: image sources of a room (None: free field).
        ambient_noise: low-frequency ambient noise (None: none).
        directivity: speakers radiate as baffled pistons (False: omnidirectional).
        driver_delay_std_s: standard deviation of each speaker's emission delay about the
            others' (a pure delay: driver, amplifier, output channel).
        air_sensor: the lab's air sensor (None: none, the speed of sound is not measured).
        camera: the cameras' effects (sim.optics; default: none, the ideal camera).
    """

    acoustic_centres: AcousticCentreModel | None = None
    rig_tolerance_m: float = 0.0
    print_scale_range: tuple[float, float] = (0.0, 0.0)
    mic_responses: MicResponseModel | None = None
    temperature_drift_k: float = 0.0
    room: RoomModel | None = None
    ambient_noise: AmbientNoiseModel | None = None
    directivity: bool = False
    driver_delay_std_s: float = 0.0
    air_sensor: AirSensorModel | None = None
    camera: CameraEffects = field(default_factory=CameraEffects)

    @classmethod
    def ideal(cls) -> LabEffects:
        return cls()

    @classmethod
    def realistic(cls) -> LabEffects:
        """Every effect on, at the magnitudes of docs/simulation.md."""
        return cls.with_effects(EFFECTS)

    @classmethod
    def with_effects(cls, names: tuple[str, ...] | list[str]) -> LabEffects:
        """The ideal lab with the named effects (see EFFECTS) turned on."""
        unknown = sorted(set(names) - set(EFFECTS))
        if unknown:
            raise SimulationInputError(f"unknown lab effect(s) {', '.join(unknown)}; choose from "
                                       f"{', '.join(EFFECTS)}")
        on = set(names)
        return cls(
            acoustic_centres=AcousticCentreModel() if "acoustic-centres" in on else None,
            rig_tolerance_m=3e-4 if "rig-tolerance" in on else 0.0,
            print_scale_range=(5e-4, 1e-3) if "print-scale" in on else (0.0, 0.0),
            mic_responses=MicResponseModel() if "mic-responses" in on else None,
            temperature_drift_k=0.4 if "air-drift" in on else 0.0,
            room=RoomModel() if "room" in on else None,
            ambient_noise=AmbientNoiseModel() if "ambient-noise" in on else None,
            directivity="directivity" in on,
            driver_delay_std_s=DRIVER_DELAY_STD_S if "driver-delays" in on else 0.0,
            air_sensor=AirSensorModel() if "air-sensor" in on else None,
            camera=CameraEffects(on=frozenset(on & set(CAMERA_EFFECTS))),
        )

    @property
    def names(self) -> tuple[str, ...]:
        """The effects that are on."""
        on = {
            "acoustic-centres": self.acoustic_centres is not None,
            "rig-tolerance": self.rig_tolerance_m > 0,
            "print-scale": self.print_scale_range[1] > 0,
            "mic-responses": self.mic_responses is not None,
            "air-drift": self.temperature_drift_k > 0,
            "room": self.room is not None,
            "ambient-noise": self.ambient_noise is not None,
            "directivity": self.directivity,
            "driver-delays": self.driver_delay_std_s > 0,
            "air-sensor": self.air_sensor is not None,
        } | {name: self.camera.has(name) for name in CAMERA_EFFECTS}
        return tuple(n for n in EFFECTS if on[n])


@dataclass(frozen=True)
class LabTruth:
    """The hidden values one world drew for its lab effects.

    Attributes:
        effects: the effects they were drawn for.
        diaphragm_offsets_m: (n_speakers, 3) each diaphragm's offset from its stated rig
            position, rig frame.
        acoustic_offsets_m: (n_speakers,) each acoustic centre's offset in front of its
            diaphragm at the model's reference frequency (zeros without the effect).
        print_scale: printed size over stated size of the checkerboard (1: to scale).
        mic_delays_s: (n_mics,) each capsule's pure delay.
        mic_resonances_hz: (n_mics,) each capsule's resonance (inf without the effect).
        reference_delay_s, reference_resonance_hz: the same for the reference microphone.
        temperature_drift_k: signed total drift over the session.
        wander_phase: phase of the slow temperature wander.
        sensor_errors: (3,) the air sensor's fixed errors: kelvin, relative humidity, pascal.
        board_sag_m: the plate's bow (sim.geometry.Rig.sag_m; its sign drawn: towards the
            printed face's side or away; 0 without the board-bow effect).
        driver_delays_s: (n_speakers,) each speaker's emission delay (zeros without the
            driver-delays effect).
    """

    effects: LabEffects
    diaphragm_offsets_m: np.ndarray
    acoustic_offsets_m: np.ndarray
    print_scale: float
    mic_delays_s: np.ndarray
    mic_resonances_hz: np.ndarray
    reference_delay_s: float
    reference_resonance_hz: float
    temperature_drift_k: float
    wander_phase: float
    ambient_directions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sensor_errors: np.ndarray = field(default_factory=lambda: np.zeros(3))
    board_sag_m: float = 0.0
    driver_delays_s: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @classmethod
    def draw(cls, effects: LabEffects, n_speakers: int, n_mics: int,
             rng: np.random.Generator) -> LabTruth:
        """Draw every hidden value (always the same number of draws, so that turning one
        effect on leaves the others' values unchanged)."""
        diaphragm = rng.normal(0.0, 1.0, (n_speakers, 3)) * effects.rig_tolerance_m
        u_centre = rng.uniform(0.0, 1.0, n_speakers)
        u_scale, sign_scale = rng.uniform(), rng.choice([-1.0, 1.0])
        z_delay = rng.normal(0.0, 1.0, n_mics + 1)
        z_res = rng.normal(0.0, 1.0, n_mics + 1)
        sign_drift, phase = rng.choice([-1.0, 1.0]), rng.uniform(0, 2 * np.pi)
        directions = rng.normal(size=(8, 3))
        z_sensor = rng.normal(size=3)
        sign_sag = rng.choice([-1.0, 1.0])
        z_driver = rng.normal(size=n_speakers)  # drawn last: the earlier draws stay the same
        ac = effects.acoustic_centres
        offsets = (np.zeros(n_speakers) if ac is None
                   else ac.offset_range_m[0] + u_centre * np.subtract(*ac.offset_range_m[::-1]))
        lo, hi = effects.print_scale_range
        mr = effects.mic_responses
        if mr is None:
            delays, res = np.zeros(n_mics + 1), np.full(n_mics + 1, np.inf)
        else:
            delays = z_delay * mr.delay_std_s
            res = mr.resonance_hz * (1.0 + mr.resonance_spread * z_res)
        amb = effects.ambient_noise
        n_waves = 0 if amb is None else amb.n_plane_waves
        return cls(
            effects=effects,
            diaphragm_offsets_m=diaphragm,
            acoustic_offsets_m=offsets,
            print_scale=1.0 + sign_scale * (lo + u_scale * (hi - lo)),
            mic_delays_s=delays[:n_mics], mic_resonances_hz=res[:n_mics],
            reference_delay_s=float(delays[n_mics]),
            reference_resonance_hz=float(res[n_mics]),
            temperature_drift_k=float(sign_drift * effects.temperature_drift_k),
            wander_phase=float(phase),
            ambient_directions=directions[:n_waves] / np.linalg.norm(directions[:n_waves],
                                                                     axis=1, keepdims=True),
            sensor_errors=(np.zeros(3) if effects.air_sensor is None else z_sensor * np.array(
                [effects.air_sensor.temperature_std_k, effects.air_sensor.relative_humidity_std,
                 effects.air_sensor.pressure_std_pa])),
            board_sag_m=(float(sign_sag * effects.camera.board_bow_m)
                         if effects.camera.has("board-bow") else 0.0),
            driver_delays_s=z_driver * effects.driver_delay_std_s,
        )

    def physical_rig(self, stated: Rig) -> Rig:
        """The rig as built: the pattern printed at `print_scale`, the diaphragms off their
        stated positions, the plate bowed by `board_sag_m` with the speakers in it (each
        moved along Z by the bow's height at its place; the rig frame stays the print's:
        origin at its extreme corner)."""
        bowed = replace(stated, square_m=stated.square_m * self.print_scale,
                        sag_m=self.board_sag_m)
        speakers = stated.speakers_m + self.diaphragm_offsets_m
        speakers[:, 2] += bowed.bow_height_m(stated.speakers_m[:, 0], stated.speakers_m[:, 1])
        return replace(bowed, speakers_m=speakers)

    def acoustic_offset_m(self, freqs_hz: np.ndarray) -> np.ndarray:
        """(n_speakers, n_freq) offset of each acoustic centre in front of its diaphragm."""
        freqs = np.asarray(freqs_hz, dtype=np.float64)
        ac = self.effects.acoustic_centres
        if ac is None:
            return np.zeros((self.acoustic_offsets_m.size, freqs.size))
        octaves = np.log2(np.maximum(freqs, 1.0) / ac.reference_hz)
        return self.acoustic_offsets_m[:, None] + ac.slope_m_per_octave * octaves[None, :]

    def temperature_offset_k(self, progress: float) -> float:
        """Air temperature minus its value at the start, at `progress` (0: the start of the
        session, 1: its last pose): the drift plus a slow wander of a tenth of it."""
        p = float(np.clip(progress, 0.0, 1.0))
        wander = 0.1 * abs(self.temperature_drift_k) * (np.sin(2 * np.pi * p + self.wander_phase)
                                                        - np.sin(self.wander_phase))
        return self.temperature_drift_k * p + wander

    def mic_response(self, freqs_hz: np.ndarray) -> np.ndarray:
        """(n_mics, n_freq) complex response of every array capsule (gain excluded)."""
        return _capsule_response(freqs_hz, self.mic_delays_s, self.mic_resonances_hz,
                                 self._q())

    def reference_response(self, freqs_hz: np.ndarray) -> np.ndarray:
        """(n_freq,) complex response of the reference microphone (gain excluded)."""
        return _capsule_response(freqs_hz, np.array([self.reference_delay_s]),
                                 np.array([self.reference_resonance_hz]), self._q())[0]

    def _q(self) -> float:
        mr = self.effects.mic_responses
        return 1.0 if mr is None else mr.q

    def to_json(self) -> dict:
        return {
            "effects": list(self.effects.names),
            "diaphragm_offsets_m": self.diaphragm_offsets_m.tolist(),
            "acoustic_offsets_m": self.acoustic_offsets_m.tolist(),
            "acoustic_centre_reference_hz": (None if self.effects.acoustic_centres is None
                                             else self.effects.acoustic_centres.reference_hz),
            "acoustic_centre_slope_m_per_octave": (
                0.0 if self.effects.acoustic_centres is None
                else self.effects.acoustic_centres.slope_m_per_octave),
            "print_scale": self.print_scale,
            "mic_delays_s": self.mic_delays_s.tolist(),
            "mic_resonances_hz": [None if not np.isfinite(f) else float(f)
                                  for f in self.mic_resonances_hz],
            "temperature_drift_k": self.temperature_drift_k,
            "air_sensor_errors": {"temperature_k": float(self.sensor_errors[0]),
                                  "relative_humidity": float(self.sensor_errors[1]),
                                  "pressure_pa": float(self.sensor_errors[2])},
            "board_bow": {"sag_m": self.board_sag_m,
                          "shape": "Z = sag_m (1 - rho^2 / rho_c^2), rho from the plate's "
                                   "centre, rho_c its half-diagonal (sim.geometry.Rig.sag_m)"},
            "driver_delays_s": self.driver_delays_s.tolist(),
            "camera": self.effects.camera.to_json(),
        }


def _capsule_response(freqs_hz: np.ndarray, delays_s: np.ndarray, resonances_hz: np.ndarray,
                      q: float) -> np.ndarray:
    """(n, n_freq) exp(-j 2 pi f d) / (1 + j (f / f_r) / q - (f / f_r)^2) per capsule."""
    f = np.asarray(freqs_hz, dtype=np.float64)[None, :]
    x = f / resonances_hz[:, None]  # 0 for an infinite resonance: a pure delay
    return np.exp(-2j * np.pi * f * delays_s[:, None]) / (1.0 + 1j * x / q - x**2)
