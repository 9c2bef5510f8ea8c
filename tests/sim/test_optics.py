"""Tests of the realistic lab's camera effects (sim.optics, sim.sensor, their use in sim.light):
each against its definition, on small images."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from sim.capture import SimulationOptions, world_for
from sim.geometry import CameraModel, Rig, RigidTransform, pinhole, rotation_from_rotvec
from sim.lab import LabEffects, LabTruth
from sim.light import WHITE_GREY, render_rig_image
from sim.optics import CameraEffects, LensModel, LightModel, SensorModel
from sim.sensor import exposed

FACING_CAMERA = np.diag([1.0, -1.0, -1.0])
"""Rig orientation whose printed face (+Z) looks back at camera 0."""
FLAT = (0.0, 0.0, 0.0, 0.0, 0.0)


def _effects(*names: str, **models: object) -> CameraEffects:
    return CameraEffects(on=frozenset(names), **models)  # type: ignore[arg-type]


def _facing(rig: Rig, centre_m: tuple[float, float, float], tilt_rad: float = 0.0
            ) -> RigidTransform:
    """The rig facing camera 0, tilted about its Y axis, the pattern centre at `centre_m`."""
    R = rotation_from_rotvec(np.array([0.0, tilt_rad, 0.0])) @ FACING_CAMERA
    return RigidTransform(R, np.asarray(centre_m) - R @ rig.centre())


def _small_camera(focal_px: float, width: int = 160, height: int = 120) -> CameraModel:
    return pinhole("small", width=width, height=height, focal_px=focal_px, dist=FLAT)


def test_noise_variance_follows_shot_plus_read_noise() -> None:
    """Linear output (no gamma): the variance of a flat level L is
    (L e + read^2) / e^2 + 1 / 12 digital numbers^2 (e electrons per DN, 1/12: rounding)."""
    sensor = SensorModel()
    e = sensor.electrons_per_dn
    levels = np.repeat(np.array([10.0, 60.0, 200.0], dtype=np.float32), 40_000).reshape(3, -1)
    out = exposed(levels, np.random.default_rng(1), 2.0, _effects("sensor-noise"))

    measured = out.astype(np.float64).var(axis=1)
    expected = (levels[:, 0] * e + sensor.read_noise_e**2) / e**2 + 1 / 12
    np.testing.assert_allclose(measured, expected, rtol=0.04)
    assert measured[2] > 4 * measured[0]  # shot noise: not the ideal world's fixed 2 grey


def test_fixed_pattern_is_the_cameras_own_and_the_same_in_every_frame() -> None:
    """PRNU and DSNU: a flat level L deviates by sqrt((prnu L)^2 + (dsnu / e)^2) per pixel
    (plus rounding), the same in every frame of a camera, another in another camera."""
    sensor = SensorModel()
    flat = np.full((200, 200), 150.0, dtype=np.float32)
    effects = _effects("fixed-pattern")
    first = exposed(flat, np.random.default_rng(1), 0.0, effects, camera_key=(0, 0))
    again = exposed(flat, np.random.default_rng(2), 0.0, effects, camera_key=(0, 0))
    other = exposed(flat, np.random.default_rng(1), 0.0, effects, camera_key=(0, 1))

    np.testing.assert_array_equal(first, again)
    assert np.mean(first != other) > 0.5
    expected = np.hypot(sensor.prnu * 150.0, sensor.dsnu_e / sensor.electrons_per_dn)
    std = first.astype(np.float64).std()
    assert abs(std**2 - expected**2 - 1 / 12) < 0.15 * expected**2


def test_gamma_encodes_before_the_8_bit_rounding() -> None:
    linear = np.linspace(-5.0, 260.0, 531, dtype=np.float32)[None, :]
    out = exposed(linear, np.random.default_rng(0), 0.0, _effects("gamma"))

    expected = np.rint(255.0 * (np.clip(linear, 0, 255) / 255.0) ** (1 / 2.2))
    difference = np.abs(out.astype(np.float64) - expected)
    assert difference.max() <= 1 and difference.mean() < 0.02  # ties may round either way
    code = dict(zip(linear.ravel().tolist(), out.ravel().tolist(), strict=True))
    assert code[2.0] - code[1.0] >= 7  # the dark end spread over many codes
    assert code[255.0] - code[254.0] <= 1  # the bright end squeezed


def test_vignetting_at_the_image_corner_is_cos4_of_its_ray() -> None:
    camera = _small_camera(100.0)
    rng = np.random.default_rng(0)
    plain = render_rig_image(camera, Rig(), None, rng, noise_grey=0.0, blur_sigma_px=0.0)
    dimmed = render_rig_image(camera, Rig(), None, rng, noise_grey=0.0, blur_sigma_px=0.0,
                              effects=_effects("vignetting"))

    x, y = (np.array([0.0, 0.0]) - camera.K[:2, 2]) / camera.K[0, 0]  # pixel (0, 0)'s ray
    cos4 = (1.0 / np.sqrt(1.0 + x * x + y * y)) ** 4
    assert cos4 < 0.5  # a corner well off the axis
    assert dimmed[0, 0] == pytest.approx(plain[0, 0] * cos4, abs=0.75)
    centre = tuple(np.round(camera.K[1::-1, 2]).astype(int))
    assert abs(int(dimmed[centre]) - int(plain[centre])) <= 1


def _edge_width_px(image: np.ndarray, camera: CameraModel, rig: Rig,
                   pose: RigidTransform) -> float:
    """RMS width (pixels) of the vertical edge X = 3 s near the pattern's centre, at
    Y = 4.5 s: the second moment of the row's gradient."""
    s = rig.square_m
    u, v = camera.project(pose.apply(np.array([[3 * s, 4.5 * s, 0.0]])))[0]
    columns = np.arange(round(u) - 8, round(u) + 9)
    gradient = np.abs(np.diff(image[round(v), columns].astype(np.float64)))
    centres = columns[:-1] + 0.5
    mean = np.sum(gradient * centres) / gradient.sum()
    return float(np.sqrt(np.sum(gradient * (centres - mean) ** 2) / gradient.sum()))


def test_defocus_blur_grows_with_the_distance_from_focus() -> None:
    """Thin lens, f/2 focused at 1.2 m: a board square-on at depth s is blurred by the lens's
    own 0.6 px and, added in quadrature, a quarter of the circle of confusion
    (f / N) |s - s_f| / s f / (s_f - f) (the sigma of a uniform disc of that diameter)."""
    camera, rig, lens = _small_camera(1000.0), Rig(), LensModel()
    f_m = 1000.0 * lens.pixel_pitch_m
    widths = {}
    for depth in (1.2, 0.45):
        pose = _facing(rig, (0.0, 0.0, depth))
        defocused = render_rig_image(camera, rig, pose, np.random.default_rng(0),
                                     noise_grey=0.0, blur_sigma_px=0.6,
                                     effects=_effects("defocus"))
        coc_px = (f_m / lens.f_number) * abs(depth - 1.2) / depth * f_m / (1.2 - f_m) / 3.75e-6
        stated = render_rig_image(camera, rig, pose, np.random.default_rng(0), noise_grey=0.0,
                                  blur_sigma_px=float(np.hypot(0.6, coc_px / 4)))
        assert np.abs(defocused.astype(int) - stated).max() <= 1
        widths[depth] = _edge_width_px(defocused, camera, rig, pose)

    assert coc_px > 2.5  # at 0.45 m
    assert widths[0.45] > widths[1.2] + 0.2


def test_bowed_board_renders_its_stated_sag() -> None:
    """The corners found in the image of a bowed plate are the bowed face's (Z = the sag's
    paraboloid), not the flat print's, and the rig as built carries the drawn sag."""
    truth = LabTruth.draw(LabEffects.with_effects(["board-bow"]), 6, 4,
                          np.random.default_rng([0, 7]))
    assert abs(truth.board_sag_m) == CameraEffects().board_bow_m
    built = truth.physical_rig(Rig())
    assert built.sag_m == truth.board_sag_m
    np.testing.assert_allclose(built.speakers_m[:, 2] - Rig().speakers_m[:, 2],
                               built.bow_height_m(*Rig().speakers_m[:, :2].T), atol=1e-12)
    centre = built.bow_height_m(np.array([0.075]), np.array([0.12]))  # the plate's centre
    assert centre[0] == pytest.approx(truth.board_sag_m)
    written = truth.to_json()
    assert written["board_bow"]["sag_m"] == truth.board_sag_m
    assert written["camera"]["effects"] == ["board-bow"]

    camera = pinhole("cam", width=640, height=480, focal_px=700.0, dist=FLAT)
    rig = replace(Rig(), sag_m=0.01)  # exaggerated: pixels of displacement, not tenths
    pose = _facing(rig, (0.0, 0.0, 0.6), tilt_rad=np.radians(35.0))
    image = render_rig_image(camera, rig, pose, np.random.default_rng(3), noise_grey=0.0)
    found, corners = cv2.findChessboardCorners(image, (rig.corners_x, rig.corners_y))
    assert found
    corners = cv2.cornerSubPix(image, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
    found_px = corners.reshape(-1, 2)
    bowed = camera.project(pose.apply(rig.corner_points()))
    flat = camera.project(pose.apply(replace(rig, sag_m=0.0).corner_points()))

    def nearest(truth_px: np.ndarray) -> np.ndarray:
        return np.linalg.norm(truth_px[:, None] - found_px[None], axis=2).min(axis=1)

    assert nearest(bowed).max() < 0.15
    assert nearest(flat).max() > 2.0


def test_lighting_follows_the_lamp_and_its_mirror_image() -> None:
    """A board square-on at depth D, a lamp at L: the highlight peaks where the camera sees
    the lamp's mirror image, L_xy D / (2 D - L_z), at specular_peak times the white; without
    gloss, the brightness of two white points is in the ratio of their
    ambient + cos(incidence) / r^2, the brightest no brighter than the print's white."""
    camera, rig, D = _small_camera(150.0), Rig(), 0.6
    pose = _facing(rig, (0.0, 0.0, D))
    lamp = np.array([0.04, 0.03, 0.2])

    def render(light: LightModel) -> np.ndarray:
        return render_rig_image(camera, rig, pose, np.random.default_rng(0), noise_grey=0.0,
                                blur_sigma_px=0.0, effects=_effects("lighting", light=light)
                                ).astype(np.float64)

    plain = render_rig_image(camera, rig, pose, np.random.default_rng(0), noise_grey=0.0,
                             blur_sigma_px=0.0).astype(np.float64)
    gloss = render(LightModel(lamp_m=tuple(lamp), ambient=1e6, specular_peak=0.2,
                              specular_sigma_m=0.01)) - plain
    peak_px = camera.project((lamp * np.array([1, 1, 0]) * D / (2 * D - lamp[2])
                              + [0, 0, D])[None, :])[0]
    v, u = np.unravel_index(np.argmax(gloss), gloss.shape)
    assert np.hypot(u - peak_px[0], v - peak_px[1]) <= 1.5
    assert gloss.max() == pytest.approx(0.2 * WHITE_GREY, abs=1.0)

    matte = render(LightModel(lamp_m=tuple(lamp), ambient=0.5, specular_peak=0.0))

    def irradiance(p: np.ndarray) -> float:  # the board's normal is -z, towards the camera
        to_lamp = lamp - p
        return 0.5 + -to_lamp[2] / np.linalg.norm(to_lamp) ** 3

    s = rig.square_m
    whites = pose.apply(np.array([[1.5 * s, 0.5 * s, 0.0], [0.5 * s, 7.5 * s, 0.0]]))
    (u1, v1), (u2, v2) = np.round(camera.project(whites)).astype(int)
    ratio = (matte[v1, u1] / plain[v1, u1]) / (matte[v2, u2] / plain[v2, u2])
    assert abs(ratio - 1.0) > 0.03  # the light is not uniform
    assert ratio == pytest.approx(irradiance(whites[0]) / irradiance(whites[1]), abs=0.01)
    assert matte.max() <= WHITE_GREY + 0.5  # the brightest white at the print's grey
