"""The simulated world: an array, the rig, the air, and the hidden truth of all three.

The world holds what the calibration must find (microphone positions, the speed of sound, the
board latencies, the camera parameters) and the state an operator changes (where the rig is,
where the reference microphone is). Levels and noise are those of a real lab by default; see
`NoiseModel` and docs/simulation.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from kernel.air import speed_of_sound

from .arrays import ArrayLayout
from .geometry import Rig, RigidTransform
from .lab import LabEffects, LabTruth
from .poses import FACING_CAMERA
from .sound import SpeakerResponse, mls_burst

if TYPE_CHECKING:
    from .live_scene import LiveScene


@dataclass(frozen=True)
class NoiseModel:
    """Levels and imperfections of the simulated lab.

    Attributes:
        scale: multiplies every random noise (acoustic and image); 0 gives a noiseless world
            (codes are still 16-bit quantized).
        array_rms_at_1m_v: RMS voltage at an array microphone 1 m from a speaker driven with a
            +-1 V MLS.
        array_snr_db_at_1m: broadband SNR of an array microphone at 1 m (the noise is white
            over the whole 0 - fs/2 band).
        reference_rms_v: RMS voltage of the reference microphone 2 mm from a speaker.
        reference_snr_db: broadband SNR of the reference microphone there.
        gain_spread_db: standard deviation of the microphones' sensitivity, in dB.
        latency_range_s: each board's input latency is uniform in this range (seconds).
        image_noise_grey: standard deviation of image sensor noise, in grey levels (the
            realistic lab's sensor-noise counts electrons instead: sim.optics).
        image_blur_px: Gaussian blur of the lens, standard deviation in pixels (its defocus
            adds to it).
    """

    scale: float = 1.0
    array_rms_at_1m_v: float = 0.1
    array_snr_db_at_1m: float = 30.0
    reference_rms_v: float = 1.0
    reference_snr_db: float = 50.0
    gain_spread_db: float = 1.0
    latency_range_s: tuple[float, float] = (1e-6, 5e-6)
    image_noise_grey: float = 2.0
    image_blur_px: float = 0.6

    def __post_init__(self) -> None:
        if self.scale < 0:
            raise ValueError(f"noise scale {self.scale} must be >= 0")

    @property
    def array_noise_v(self) -> float:
        return self.scale * self.array_rms_at_1m_v / 10 ** (self.array_snr_db_at_1m / 20)

    @property
    def reference_noise_v(self) -> float:
        return self.scale * self.reference_rms_v / 10 ** (self.reference_snr_db / 20)


@dataclass
class World:
    """The simulated lab.

    Attributes:
        layout: the array, its cameras and wiring (with the lab's lens-distortion, its
            cameras' distortion replaced by the lab's lens: sim.optics).
        rig: the calibration rig as stated (its description); the rig as built is
            `physical_rig` (the lab's print scale and speaker build errors).
        temperature_c: air temperature at the start of the session (the lab's air drift
            changes it as the session progresses).
        relative_humidity: of the air (0..1); with the temperature and the pressure it sets
            the speed of sound by Cramer's formula (kernel.air).
        pressure_pa: the air's static pressure.
        sample_rate_hz: the shared sample clock of all boards.
        noise: levels and noise.
        seed: seeds every random draw of this world (hidden parameters and noise).
        reference_distance_m: distance of the reference microphone from a speaker's acoustic
            centre during the reference recordings (paper IV-C: about 2 mm).
        body_diffraction: let sound reach microphones in the shadow of a sphere array around
            its surface (the creeping-wave path) instead of straight through it.
        speaker: the speakers' response.
        lab: the realistic lab's systematic effects (sim.lab; default: none, the ideal world).
    """

    layout: ArrayLayout
    rig: Rig = field(default_factory=Rig)
    temperature_c: float = 20.0
    relative_humidity: float = 0.45
    pressure_pa: float = 101_325.0
    sample_rate_hz: float = 96_000.0
    noise: NoiseModel = field(default_factory=NoiseModel)
    seed: int = 0
    reference_distance_m: float = 0.002
    body_diffraction: bool = False
    speaker: SpeakerResponse = field(default_factory=SpeakerResponse)
    lab: LabEffects = field(default_factory=LabEffects)

    def __post_init__(self) -> None:
        if self.lab.camera.has("lens-distortion"):  # the cameras' lenses as built
            dist = np.array(self.lab.camera.lens.distortion, dtype=np.float64)
            self.layout = replace(self.layout, cameras=tuple(
                replace(c, dist=dist) for c in self.layout.cameras))
        rng = np.random.default_rng([self.seed, 1])
        self.lab_truth = LabTruth.draw(self.lab, self.rig.n_speakers, self.layout.n_mics,
                                       np.random.default_rng([self.seed, 7]))
        self.physical_rig = self.lab_truth.physical_rig(self.rig)
        self.session_progress = 0.0
        self.mic_gains = 10 ** (rng.normal(0, self.noise.gain_spread_db, self.layout.n_mics) / 20)
        lo, hi = self.noise.latency_range_s
        self.board_latencies_s = rng.uniform(lo, hi, len(self.layout.boards))
        self.speaker_pressure_gain = self.noise.array_rms_at_1m_v / self._unit_drive_rms()
        self.reference_gain = self.noise.reference_rms_v * self.reference_distance_m / (
            self.speaker_pressure_gain * self._unit_drive_rms()
        )
        self.rig_pose = RigidTransform(FACING_CAMERA, np.array([-0.075, 0.12, 0.8]))
        self.reference_mic_m: np.ndarray | None = None
        self.reference_near_speaker: int | None = None
        self.rig_in_view = True
        self._rig_pose_for_bursts: RigidTransform | None = None
        self.live_scene: LiveScene | None = None  # sources playing continuously (live mode)

    @property
    def air_temperature_c(self) -> float:
        """The air's temperature now (the start temperature plus the lab's drift so far)."""
        return self.temperature_c + self.lab_truth.temperature_offset_k(self.session_progress)

    @property
    def speed_of_sound_m_s(self) -> float:
        """The speed of sound now, m/s."""
        return float(speed_of_sound(self.air_temperature_c, self.relative_humidity,
                                    self.pressure_pa))

    def set_session_progress(self, progress: float) -> None:
        """Where the session is in time, 0 (its start) to 1 (its last pose): the air drifts."""
        self.session_progress = float(progress)

    def _unit_drive_rms(self) -> float:
        """RMS of the speaker's acoustic output for a +-1 V MLS drive (order 14)."""
        x = mls_burst(14)
        n = len(x)
        h = self.speaker.frequency_response(np.fft.rfftfreq(n, 1 / self.sample_rate_hz),
                                            self.sample_rate_hz)
        y = np.fft.irfft(np.fft.rfft(x) * h, n)
        return float(np.sqrt(np.mean(y**2)))

    def speaker_positions(self) -> np.ndarray:
        """(n_speakers, 3) speaker diaphragm centres in the camera-0 frame, at the current pose
        (the acoustic centres in the ideal world)."""
        return self.rig_pose.apply(self.physical_rig.speakers_m)

    def acoustic_centres_m(self, frequency_hz: float | None = None) -> np.ndarray:
        """(n_speakers, 3) where each speaker's sound appears to come from in the far field,
        camera-0 frame, at the current pose (at the lab model's reference frequency when
        `frequency_hz` is None)."""
        ac = self.lab.acoustic_centres
        default_hz = ac.reference_hz if ac is not None else 1000.0
        f = default_hz if frequency_hz is None else frequency_hz
        offsets = self.lab_truth.acoustic_offset_m(np.array([f]))[:, 0]
        return self.speaker_positions() + offsets[:, None] * self.rig_normal()

    def rig_normal(self) -> np.ndarray:
        """Unit vector out of the rig's printed face, in the camera-0 frame."""
        return self.rig_pose.R[:, 2]

    def place_rig(self, pose: RigidTransform, in_view: bool = True,
                  pose_for_bursts: RigidTransform | None = None) -> None:
        """Hold the rig at `pose`; `pose_for_bursts`: the rig is nudged there before the first
        burst that follows (after the images: the moved-pose mistake, sim.mistakes)."""
        self.rig_pose = pose
        self.rig_in_view = in_view
        self._rig_pose_for_bursts = pose_for_bursts

    def start_scan(self) -> None:
        """A scan starts (the trigger): a rig to be nudged before the bursts moves now."""
        if self._rig_pose_for_bursts is not None:
            self.rig_pose, self._rig_pose_for_bursts = self._rig_pose_for_bursts, None

    def place_reference_mic(self, position_m: np.ndarray | None,
                            near_speaker: int | None = None) -> None:
        """Put the reference microphone at `position_m` (None: nowhere); `near_speaker` says it
        sits in that speaker's near field (a reference recording): it hears the diaphragm."""
        self.reference_mic_m = None if position_m is None else np.asarray(position_m, float)
        self.reference_near_speaker = near_speaker

    def reference_position_at_speaker(self, speaker: int,
                                      distance_m: float | None = None) -> np.ndarray:
        """Where the reference microphone sits for speaker `speaker`'s reference recording:
        `distance_m` (default `reference_distance_m`) in front of its diaphragm."""
        d = self.reference_distance_m if distance_m is None else distance_m
        return self.speaker_positions()[speaker] + d * self.rig_normal()
