"""The docs' worked example of `micam import` (docs/import.md, "A worked example"): a lab
unlike micam's, written with code of its own as another lab's recorder would leave it, a plain
folder of WAV and PNG files and one TOML file (`micam example import DIR` writes it).

The rig: 48 microphones on 8 boards of 6 channels, one camera, a board printed with the
opposite colour convention (the square at the origin light), the reference microphone on
channel 0 of board 0, recorded only in the reference recordings (in the poses that channel
records microphone 0), a known air temperature, 48 kS/s. The acoustics are this module's own:
a band-limited MLS, exact fractional delays r / c + the board's latency as a linear phase,
1 / r spreading, per-microphone gains, white noise. Only the camera's images come from the
project's renderer (sim.light: "the camera"), of rig poses chosen here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy.signal
import soundfile as sf

from kernel.air import speed_of_sound as air_speed_of_sound
from kernel.rigid import RigidTransform, rotation_from_rotvec

from .geometry import Rig, pinhole
from .light import render_rig_image

FS = 48_000
MLS_ORDER = 11
SILENCE_BEFORE = 256
SILENCE_AFTER = 640
EXTRA_RECORDED = 128
N_SAMPLES = SILENCE_BEFORE + 2**MLS_ORDER - 1 + SILENCE_AFTER + EXTRA_RECORDED
N_BOARDS, CHANNELS_PER_BOARD = 8, 6
N_MICS = N_BOARDS * CHANNELS_PER_BOARD
TEMPERATURE_C, TEMPERATURE_STD_C = 24.0, 0.1
HUMIDITY, HUMIDITY_STD = 0.45, 0.02
SPEAKERS_M = np.array([[-60.0, 0.0, -2.5], [210.0, 0.0, -2.5], [-60.0, 240.0, -2.5],
                       [210.0, 240.0, -2.5], [-60.0, 120.0, -2.5], [210.0, 120.0, -2.5]]) / 1e3
REFERENCE_DISTANCES_M = (0.002, 0.0025, 0.002, 0.003, 0.002, 0.0025)
BAND_HZ = (300.0, 20_000.0)
ARRAY_RMS_AT_1M = 0.1
ARRAY_SNR_DB_AT_1M = 30.0
REFERENCE_SNR_DB = 50.0
GAIN_SPREAD_DB = 1.0
LATENCY_RANGE_S = (1e-6, 5e-6)
FACING = np.diag([1.0, -1.0, -1.0])  # rig X along camera x, rig Y up, rig Z towards the camera


def speed_of_sound(temperature_c: float, humidity: float = HUMIDITY) -> float:
    """This lab's air (Cramer's formula, the physics every lab shares)."""
    return float(air_speed_of_sound(temperature_c, humidity))


@dataclass(frozen=True)
class ForeignWorld:
    """The truth of the foreign lab (camera-0 frame, metres, seconds)."""

    mics_m: np.ndarray
    gains: np.ndarray
    latencies_s: np.ndarray
    poses: list[RigidTransform]  # rig -> camera 0
    speed_of_sound_m_s: float
    seed: int

    @property
    def group_names(self) -> list[str]:
        return [f"board{b}" for b in range(N_BOARDS)]

    def truth(self) -> dict:
        """The lab's truth as a micam truth file (`micam calibrate --truth`)."""
        return {
            "microphones": [{"id": m, "position_m": self.mics_m[m].tolist()}
                            for m in range(N_MICS)],
            "speed_of_sound_m_s": self.speed_of_sound_m_s,
            "cameras": [{**pinhole("cam0").to_json(), "name": "camera"}],
            "board_latencies_s": {n: float(lat) for n, lat in
                                  zip(self.group_names, self.latencies_s, strict=True)},
        }


def make_world(seed: int = 5, n_poses: int = 6) -> ForeignWorld:
    """48 microphones in a shallow dish around the camera, poses 0.55-0.85 m away, tilted."""
    rng = np.random.default_rng([seed, 1])
    radius = np.sqrt(rng.uniform(0.05**2, 0.3**2, N_MICS))
    angle = rng.uniform(0, 2 * np.pi, N_MICS)
    mics = np.stack([radius * np.cos(angle), radius * np.sin(angle),
                     -0.3 * radius**2 + rng.uniform(-0.01, 0.01, N_MICS)], axis=1)
    gains = 10 ** (rng.normal(0.0, GAIN_SPREAD_DB, N_MICS) / 20)
    latencies = rng.uniform(*LATENCY_RANGE_S, N_BOARDS)
    centre = np.array([0.075, 0.12, 0.0])  # the pattern's centre, rig frame
    poses = []
    for k in range(n_poses):
        tilt = np.radians(30.0) * np.array([np.cos(2.1 * k + 0.4), np.sin(2.1 * k + 0.4), 0.0])
        R = rotation_from_rotvec(tilt) @ FACING
        depth = 0.55 + 0.3 * k / max(n_poses - 1, 1)
        target = np.array([0.04 * np.cos(1.3 * k), 0.03 * np.sin(1.7 * k), depth])
        poses.append(RigidTransform(R, target - R @ centre))
    return ForeignWorld(mics, gains, latencies, poses, speed_of_sound(TEMPERATURE_C), seed)


def _drive() -> np.ndarray:
    """The burst the speakers play: silence, one MLS period (+-1), silence, extra."""
    seq, _ = scipy.signal.max_len_seq(MLS_ORDER)
    x = np.zeros(N_SAMPLES)
    x[SILENCE_BEFORE:SILENCE_BEFORE + seq.size] = 2.0 * seq - 1.0
    return x


def _delayed(drive: np.ndarray, delays_s: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """(n_samples, n_paths): the drive through the speaker's band-pass, delayed by each path's
    delay (linear phase on a zero-padded FFT, exact for this band-limited signal) and scaled."""
    n_fft = 2 * N_SAMPLES
    freqs = np.fft.rfftfreq(n_fft, 1.0 / FS)
    sos = scipy.signal.butter(2, BAND_HZ, btype="bandpass", fs=FS, output="sos")
    _, response = scipy.signal.sosfreqz(sos, worN=freqs, fs=FS)
    spectrum = np.fft.rfft(drive, n_fft) * response
    phase = np.exp(-2j * np.pi * np.outer(delays_s, freqs))
    out = np.fft.irfft(phase * spectrum[None, :] * gains[:, None], n_fft, axis=1)
    return out[:, :N_SAMPLES].T


def _unit_rms(drive: np.ndarray) -> float:
    return float(np.sqrt(np.mean(_delayed(drive, np.zeros(1), np.ones(1)) ** 2)))


def _board_of_column() -> np.ndarray:
    return np.repeat(np.arange(N_BOARDS), CHANNELS_PER_BOARD)


def write_folder(world: ForeignWorld, folder: Path) -> Path:
    """The recorder's folder: reference/, pose_NN/ with WAV and PNG files, and import.toml.

    Returns the TOML file's path.
    """
    rng = np.random.default_rng([world.seed, 2])
    drive = _drive()
    level = ARRAY_RMS_AT_1M / _unit_rms(drive)  # pressure gain: rms at 1 m
    noise = ARRAY_RMS_AT_1M / 10 ** (ARRAY_SNR_DB_AT_1M / 20)
    c = world.speed_of_sound_m_s
    board = _board_of_column()
    folder.mkdir(parents=True, exist_ok=True)

    def record(speaker_m: np.ndarray) -> np.ndarray:
        r = np.linalg.norm(world.mics_m - speaker_m, axis=1)
        x = _delayed(drive, r / c + world.latencies_s[board], level * world.gains / r)
        return x + rng.normal(0.0, noise, x.shape)

    (folder / "reference").mkdir(exist_ok=True)
    for k in range(len(SPEAKERS_M)):
        # the array hears it too; column 0 holds the reference instead
        x = record(world.poses[0].apply(SPEAKERS_M[k]))
        d = REFERENCE_DISTANCES_M[k]
        ref = _delayed(drive, np.array([d / c + world.latencies_s[0]]), np.array([level / d]))
        ref_rms = float(np.sqrt(np.mean(ref**2)))
        x[:, 0] = ref[:, 0] + rng.normal(0.0, ref_rms / 10 ** (REFERENCE_SNR_DB / 20), N_SAMPLES)
        sf.write(folder / "reference" / f"speaker{k}.wav", x.astype(np.float32), FS,
                 subtype="FLOAT")

    camera = pinhole("cam0")
    rig = Rig(origin_square="light")
    for i, pose in enumerate(world.poses):
        pose_dir = folder / f"pose_{i:02d}"
        pose_dir.mkdir(exist_ok=True)
        image = render_rig_image(camera, rig, pose,
                                 np.random.default_rng([world.seed, 3, i]))
        cv2.imwrite(str(pose_dir / "camera.png"), image)
        for k in range(len(SPEAKERS_M)):
            x = record(pose.apply(SPEAKERS_M[k]))
            sf.write(pose_dir / f"speaker{k}.wav", np.clip(x / 2.0, -1, 1), FS,
                     subtype="PCM_24")
    toml = folder / "import.toml"
    toml.write_text(import_toml(len(world.poses)))
    return toml


def import_toml(n_poses: int) -> str:
    """The lab's description of its rig, array and recordings."""
    speakers = ", ".join(f"[{x:.4f}, {y:.4f}, {z:.4f}]" for x, y, z in SPEAKERS_M)
    lines = [
        "# A foreign lab: 8 boards of 6 channels, one camera, reference mic on board 0",
        f"sample_rate_hz = {FS}",
        "",
        "[rig]",
        "corners_x = 6",
        "corners_y = 9",
        "square_m = 0.030",
        'origin_square = "light"',
        f"speakers_m = [{speakers}]",
        "",
        "[reference]",
        'group = "board0"',
        "reference_recordings_column = 0",
        f"distance_from_speaker_m = {list(REFERENCE_DISTANCES_M)}",
        "",
        "[burst]",
        f"silence_before_samples = {SILENCE_BEFORE}",
        f"mls_order = {MLS_ORDER}",
        f"silence_after_samples = {SILENCE_AFTER}",
        f"extra_recorded_samples = {EXTRA_RECORDED}",
        "",
        "[air]",
        f"temperature_c = {TEMPERATURE_C}",
        f"temperature_std_c = {TEMPERATURE_STD_C}",
        f"relative_humidity = {HUMIDITY}",
        f"relative_humidity_std = {HUMIDITY_STD}",
        "",
        "[[cameras]]",
        'name = "camera"',
        "width = 1280",
        "height = 960",
        "",
    ]
    for b in range(N_BOARDS):
        cols = list(range(b * CHANNELS_PER_BOARD, (b + 1) * CHANNELS_PER_BOARD))
        lines += ["[[channels]]", f'group = "board{b}"', f"columns = {cols}",
                  f"mic_ids = {cols}", ""]
    refs = ", ".join(f'"reference/speaker{k}.wav"' for k in range(len(SPEAKERS_M)))
    lines += ["[recordings]", f"references = [{refs}]", ""]
    for i in range(n_poses):
        bursts = ", ".join(f'"pose_{i:02d}/speaker{k}.wav"' for k in range(len(SPEAKERS_M)))
        lines += ["[[recordings.poses]]", f"bursts = [{bursts}]",
                  f'images = {{ camera = "pose_{i:02d}/camera.png" }}', ""]
    return "\n".join(lines)
