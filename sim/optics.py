"""The realistic lab's cameras: what a real UVC or industrial camera does to the light.

The ideal world's camera adds 2 grey levels of Gaussian noise and a 0.6 px Gaussian blur to a
perfectly lit, perfectly flat board (sim.light); real calibration cameras give corner residuals
of 0.03-0.2 px. Each effect below is one reason, switchable by name like the acoustic effects
of sim.lab (`micam simulate --effect NAME`), with the magnitudes of docs/simulation.md:

- sensor-noise: photon shot noise and read noise of a small CMOS sensor at the stated
  exposure and analog gain (electrons; the ideal world's fixed Gaussian noise is replaced).
- fixed-pattern: each pixel's own gain (PRNU) and dark offset (DSNU), fixed per camera.
- defocus: a fixed-focus lens's thin-lens blur for each pixel's depth on the board.
- lens-distortion: a short M12 lens's strong barrel distortion, with tangential and third-order
  radial terms (OpenCV's 5-coefficient model, which the calibration fits).
- vignetting: the cos^4 fall-off of the irradiance with the chief ray's angle.
- lighting: a lamp beside the array lights the board unevenly (cos / r^2), and the glossy print
  reflects it as a soft specular highlight.
- board-bow: the plate is bowed, a paraboloid sag (sim.geometry.Rig.sag_m).
- gamma: the camera's 1 / 2.2 gamma curve before its 8-bit output.

The camera delivers YUYV, whose luma for a grey image is the 8-bit frame itself; MJPEG at a
stated quality is the mjpeg mistake's codec (`--mistake mjpeg=QUALITY`, sim.mistakes), not a
second switch here: the design counts MJPEG-compressed frames among a capture's mistakes, and
the calibration notes them as a finding.

The grey levels sim.light renders (the print's 40 and 210) are the linear signal, in digital
numbers of the 8-bit output, at the image centre for the stated exposure: sensor-noise turns
them into electrons with `SensorModel.electrons_per_dn`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

CAMERA_EFFECTS = ("sensor-noise", "fixed-pattern", "defocus", "lens-distortion", "vignetting",
                  "lighting", "board-bow", "gamma")
"""The camera effects' names, in the order of docs/simulation.md's table."""


@dataclass(frozen=True)
class SensorModel:
    """A 1/3-inch 1280 x 960 CMOS sensor (3.75 um pixels) at an indoor exposure.

    Attributes:
        full_well_e: electrons a pixel holds.
        analog_gain: the gain at which the camera runs (10 ms in a room lit for people, about
            250 lux: the auto exposure of a webcam turns it up to about 16).
        read_noise_e: read noise, electrons RMS, referred to the pixel (at that gain).
        prnu: photo-response non-uniformity, relative gain spread between pixels (RMS).
        dsnu_e: dark-signal non-uniformity, electrons RMS (dark current over 10 ms and the
            pixels' offsets).
    """

    full_well_e: float = 10_000.0
    analog_gain: float = 16.0
    read_noise_e: float = 5.0
    prnu: float = 0.01
    dsnu_e: float = 4.0

    @property
    def electrons_per_dn(self) -> float:
        """Electrons per digital number of the linear 8-bit signal: full well over 255
        levels, divided by the gain (2.45 e-/DN at gain 16: the print's white, 210 DN, is
        about 515 e-, its shot noise 23 e- = 9.3 DN)."""
        return self.full_well_e / (255.0 * self.analog_gain)


@dataclass(frozen=True)
class LensModel:
    """A fixed-focus M12 lens: focal length 3.75 mm (1000 px at 3.75 um pixels).

    Attributes:
        pixel_pitch_m: the sensor's pixel pitch (the lens's focal length in metres is the
            camera's focal length in pixels times this).
        f_number: the aperture, f / N.
        focus_m: the object distance the lens is focused at (near its hyperfocal distance,
            as a fixed-focus module is set for a room).
        distortion: (k1, k2, p1, p2, k3), OpenCV's order: about 13 % barrel at the image
            corners, tangential terms of a lens decentred by a few micrometres.
    """

    pixel_pitch_m: float = 3.75e-6
    f_number: float = 2.0
    focus_m: float = 1.2
    distortion: tuple[float, float, float, float, float] = (-0.22, 0.09, 0.0012, -0.0009,
                                                            -0.015)

    def blur_sigma_px(self, depth_m: np.ndarray, focal_px: float) -> np.ndarray:
        """Standard deviation (pixels) of the defocus blur of points at `depth_m`.

        Thin lens: a point at depth s images to a disc of diameter
        c = (f / N) |s - s_f| / s * f / (s_f - f) on the sensor (s_f the focus distance); a
        uniform disc of diameter c has the standard deviation c / 4 along each axis, the
        Gaussian's sigma used here.
        """
        f = focal_px * self.pixel_pitch_m
        s = np.maximum(np.asarray(depth_m, dtype=np.float32), np.float32(f * 1.01))
        coc_m = (f / self.f_number) * np.abs(s - self.focus_m) / s * f / (self.focus_m - f)
        return coc_m / np.float32(4.0 * self.pixel_pitch_m)


@dataclass(frozen=True)
class LightModel:
    """A lamp beside the array and the print's gloss.

    Attributes:
        lamp_m: the lamp's position, camera-0 frame (above and to the right of the array).
        ambient: the room's diffuse light on the board, in units of the lamp's at 1 m head
            on (the camera's auto exposure then scales the plate's brightest point to the
            print's stated greys).
        specular_peak: the highlight's peak over the print's white (a semi-gloss print; with
            the white at 210 of 255, it stays below saturation).
        specular_sigma_m: its Gaussian width on the board (the print's roughness spreads the
            lamp's mirror image).
    """

    lamp_m: tuple[float, float, float] = (0.6, -0.8, 0.2)
    ambient: float = 0.5
    specular_peak: float = 0.1
    specular_sigma_m: float = 0.04

    def irradiance(self, x: np.ndarray, y: np.ndarray, z: np.ndarray, normal: np.ndarray,
                   lamp: np.ndarray) -> np.ndarray:
        """Light falling on board points (x, y, z) (arrays of one shape, metres) of normal
        `normal` from a lamp at `lamp` (same frame): the room's `ambient` plus the lamp's
        cos(incidence) / r^2 (in units of the lamp's light at 1 m, head on)."""
        to_lamp = [np.float32(lamp[i]) - c for i, c in enumerate((x, y, z))]
        r2 = to_lamp[0] ** 2 + to_lamp[1] ** 2 + to_lamp[2] ** 2
        along_normal = sum(np.float32(n) * c for n, c in zip(normal, to_lamp, strict=True))
        cos_in = np.maximum(along_normal, np.float32(0.0)) / np.sqrt(r2)
        return np.float32(self.ambient) + cos_in / r2


@dataclass(frozen=True)
class CameraEffects:
    """Which camera effects are on, and the stated camera they describe.

    Attributes:
        on: the names (CAMERA_EFFECTS) of the effects that are on.
        sensor, lens, light: the stated sensor, lens and light (used by the effects that are
            on).
        board_bow_m: the plate's sag at its centre with board-bow on (its sign is drawn).
        gamma: the camera's gamma (the output is linear ** (1 / gamma)).
    """

    on: frozenset[str] = frozenset()
    sensor: SensorModel = field(default_factory=SensorModel)
    lens: LensModel = field(default_factory=LensModel)
    light: LightModel = field(default_factory=LightModel)
    board_bow_m: float = 0.5e-3
    gamma: float = 2.2

    def has(self, name: str) -> bool:
        """Whether effect `name` (one of CAMERA_EFFECTS) is on."""
        return name in self.on

    def to_json(self) -> dict:
        """The stated camera of the effects that are on, for truth.json."""
        out: dict = {"effects": [n for n in CAMERA_EFFECTS if n in self.on]}
        s, lens, light = self.sensor, self.lens, self.light
        if self.on & {"sensor-noise", "fixed-pattern"}:
            out["sensor"] = {"full_well_e": s.full_well_e, "analog_gain": s.analog_gain,
                             "electrons_per_dn": s.electrons_per_dn,
                             "read_noise_e": s.read_noise_e, "prnu": s.prnu, "dsnu_e": s.dsnu_e}
        if self.has("defocus"):
            out["lens"] = {"pixel_pitch_m": lens.pixel_pitch_m, "f_number": lens.f_number,
                           "focus_m": lens.focus_m}
        if self.has("lighting"):
            out["light"] = {"lamp_m": list(light.lamp_m), "ambient": light.ambient,
                            "specular_peak": light.specular_peak,
                            "specular_sigma_m": light.specular_sigma_m}
        if self.has("gamma"):
            out["gamma"] = self.gamma
        return out


NO_CAMERA_EFFECTS = CameraEffects()
"""The ideal world's camera."""
