"""From the light on the sensor to the camera's 8-bit frame: blur, noise, gamma.

sim.light renders the ideal float image (grey levels: the linear signal in digital numbers at
the stated exposure) and hands it here. The ideal world's camera blurs it with one Gaussian,
adds Gaussian noise of a fixed grey level and rounds it to 8 bits; the realistic lab's
(sim.optics) blurs each pixel by its own defocus, counts electrons with their shot and read
noise and the pixels' fixed pattern, applies the gamma curve and rounds (the codec that
delivers the frame is sim.cameras').
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from .optics import NO_CAMERA_EFFECTS, CameraEffects, SensorModel

_FIXED_PATTERN_STREAM = 13
"""The fixed pattern's generator is (seed, this, camera): a stream of its own among the
world's (sim.world, sim.cameras, ...)."""
_SIGMA_STEP_PX = 0.05
"""Defocus blurs closer than this (pixels of sigma) across an image are one blur."""


def cos4_falloff(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """cos^4 of the angle between the optical axis and the undistorted rays (x, y, 1): the
    natural vignetting of a lens (irradiance relative to the image centre)."""
    r2 = x * x + y * y
    return 1.0 / (1.0 + r2) ** 2


def blurred(image: np.ndarray, sigma_px: np.ndarray | float) -> np.ndarray:
    """`image` blurred by a Gaussian of standard deviation `sigma_px`, one value or one per
    pixel (a float32 map: each pixel interpolated linearly between the image blurred by the
    map's smallest and largest sigma; a defocus varies slowly across a board, so that two
    blurs suffice and an edge stays symmetric about its true position)."""
    sigma = np.asarray(sigma_px, dtype=np.float32)
    lo, hi = float(sigma.min()), float(sigma.max())
    if hi - lo < _SIGMA_STEP_PX:
        return _gaussian(image, 0.5 * (lo + hi))
    sharp = _gaussian(image, lo)
    weight = (sigma - np.float32(lo)) / np.float32(hi - lo)
    return sharp + weight * (_gaussian(image, hi) - sharp)


def _gaussian(image: np.ndarray, sigma_px: float) -> np.ndarray:
    if sigma_px <= 0:
        return np.array(image, dtype=np.float32)
    return cv2.GaussianBlur(np.asarray(image, dtype=np.float32), (0, 0), sigma_px,
                            borderType=cv2.BORDER_REFLECT)


@lru_cache(maxsize=8)
def fixed_pattern(sensor: SensorModel, shape: tuple[int, int],
                  key: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(gain, offset in electrons) of every pixel of one camera's sensor: PRNU and DSNU,
    drawn once from `key` (the world's seed and the camera) and kept (read-only float32)."""
    rng = np.random.default_rng([key[0], _FIXED_PATTERN_STREAM, *key[1:]])
    gain = 1.0 + sensor.prnu * rng.standard_normal(shape, dtype=np.float32)
    offset = sensor.dsnu_e * rng.standard_normal(shape, dtype=np.float32)
    for a in (gain, offset):
        a.flags.writeable = False
    return gain, offset


def exposed(image: np.ndarray, rng: np.random.Generator, noise_grey: float,
            effects: CameraEffects = NO_CAMERA_EFFECTS, noise_scale: float = 1.0,
            camera_key: tuple[int, ...] = (0,)) -> np.ndarray:
    """The camera's 8-bit frame of the (blurred) linear image, grey levels.

    Without sensor-noise the ideal world's Gaussian noise of `noise_grey` is added; with it,
    the signal is counted in electrons (`SensorModel.electrons_per_dn`) with Gaussian noise of
    the variance of shot plus read noise (signal + read^2, electrons; exact for the hundreds
    of electrons of a print), times `noise_scale`. fixed-pattern multiplies the signal by each
    pixel's gain and adds its dark offset (`camera_key` picks the camera's pattern). gamma
    encodes the clipped linear signal as 255 (linear / 255) ** (1 / gamma). The result is
    rounded to 8 bits.
    """
    out = np.array(image, dtype=np.float32)
    sensor = effects.sensor
    e_per_dn = np.float32(sensor.electrons_per_dn)
    if effects.has("fixed-pattern"):
        gain, offset = fixed_pattern(sensor, out.shape, camera_key)
        out = out * gain + offset / e_per_dn
    if effects.has("sensor-noise"):
        electrons = np.maximum(out * e_per_dn, np.float32(0.0))
        std_e = np.sqrt(electrons + np.float32(sensor.read_noise_e**2))
        out += np.float32(noise_scale) * std_e / e_per_dn * rng.standard_normal(
            out.shape, dtype=np.float32)
    elif noise_grey > 0:
        out += np.float32(noise_grey) * rng.standard_normal(out.shape, dtype=np.float32)
    if effects.has("gamma"):
        out = 255.0 * (np.clip(out, 0, 255) / np.float32(255.0)) ** np.float32(1 / effects.gamma)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
