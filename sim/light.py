"""Light: grey camera images of the calibration rig, for OpenCV's checkerboard detector.

Each pixel centre is traced back through the camera's distortion (OpenCV's 5-coefficient
model, the exact inverse of cv2.projectPoints, which is the reference for the true corner
positions) to a ray, the ray is intersected with the rig plane, and the pixel is shaded from
the rig coordinates (X, Y) it hits. Every edge is box-filtered analytically over the pixel's
footprint on the board (its extent along X and along Y, from the Jacobian of (X, Y) with
respect to the pixel coordinates), so edges are anti-aliased like a sensor integrating light
over a pixel and the 50 % level of every edge lies exactly on the projected edge. The image is
then blurred (lens and defocus), made noisy (sensor) and quantized to 8 bits (sim.sensor).
The realistic lab's camera effects (sim.optics) act here where they act in a camera: the
plate's bow on where each ray meets the board, the lamp and the print's gloss on the light the
face sends back, vignetting on the light reaching each pixel, defocus by each pixel's depth.

Printed pattern, rig frame (see sim.geometry): (corners_x + 1) x (corners_y + 1) squares of
side s spanning X in [-s, corners_x s] and Y in [-s, corners_y s]. Square (i, j), covering
[i s, (i + 1) s] x [j s, (j + 1) s] with i, j starting at -1, is dark when i + j is even
(`Rig.origin_square` "dark", micam's print): the square on the +X +Y side of the rig origin is
dark, the two pattern corners at Y = -s are dark and the two at Y = corners_y s are white, so a
7 x 10 pattern is not symmetric under a half-turn. With `origin_square` "light" (the opposite
convention) every square has the other colour.

Pixel convention: OpenCV's, pixel (row v, column u) is centred on the point (u, v) and covers
[u - 1/2, u + 1/2] x [v - 1/2, v + 1/2].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from sim.geometry import CameraModel, Rig, RigidTransform
from sim.optics import NO_CAMERA_EFFECTS, CameraEffects
from sim.sensor import blurred, cos4_falloff, exposed

DARK_GREY = 40.0
"""Grey level of the printed dark squares (0..255)."""
WHITE_GREY = 210.0
"""Grey level of the white plate and the white squares."""
SPEAKER_GREY = 120.0
"""Grey level of the speaker discs."""
BACK_GREY = 150.0
"""Grey level of the plate seen from behind (no pattern is printed there)."""
BACKGROUND_GREY_RANGE = (60.0, 115.0)
"""Darkest and brightest grey of the background gradient, darker than the plate so that the
plate's white border stands out as in a photo."""

_FAR_M = 1.0e3
"""Board coordinate given to pixels that do not see the board plane: far outside the plate."""
_MIN_FOOTPRINT_M = 1.0e-9
"""Floor of a pixel's footprint on the board, so that box filters never divide by zero."""
_RAY_CHECK_PX = 1.0e-3
"""A pixel's ray is kept only if it reprojects within this many pixels of the pixel centre:
rays where the iterative undistortion did not converge (strong distortion, far corners)
would otherwise shade the pixel from a wrong point."""


@dataclass(frozen=True)
class _PixelRays:
    """Undistorted normalized ray (x, y, 1) of every pixel centre and its derivatives.

    All maps are float32 arrays of shape (height, width); x_u = dx/du etc. are per pixel.
    `valid` is False where the undistortion did not converge.
    """

    x: np.ndarray
    y: np.ndarray
    x_u: np.ndarray
    x_v: np.ndarray
    y_u: np.ndarray
    y_v: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True)
class _BoardHits:
    """Where each pixel's ray meets the rig plane, in rig coordinates (metres, float32 maps).

    X, Y: hit point; w_x, w_y: the pixel's footprint along X and along Y (the root sum of
    squares of the change of X, resp. Y, across one pixel in u and in v: the width of a box
    with the same spread as the pixel's footprint on that axis); depth: the hit point's z in
    the camera frame; hit: whether the ray meets the plane in front of the camera. Pixels
    whose ray misses the plane get X = Y = _FAR_M.
    """

    X: np.ndarray
    Y: np.ndarray
    w_x: np.ndarray
    w_y: np.ndarray
    depth: np.ndarray
    hit: np.ndarray

    def on_plate(self, rig: Rig) -> np.ndarray:
        """Which pixels' rays meet the rig's plate (not merely its plane)."""
        x0, x1, y0, y1 = (np.float32(v) for v in rig.plate_m)
        return self.hit & (self.X >= x0) & (self.X <= x1) & (self.Y >= y0) & (self.Y <= y1)


def render_rig_image(
    camera: CameraModel,
    rig: Rig,
    rig_to_cam0: RigidTransform | None,
    rng: np.random.Generator,
    noise_grey: float = 2.0,
    blur_sigma_px: float = 0.6,
    scene: Callable[[np.ndarray], np.ndarray] | None = None,
    effects: CameraEffects = NO_CAMERA_EFFECTS,
    camera_key: tuple[int, ...] = (0,),
    noise_scale: float = 1.0,
) -> np.ndarray:
    """Grey image (uint8, camera.height x camera.width) of the rig seen by `camera`.

    Args:
        camera: intrinsics, distortion and pose (camera.cam0_to_cam) of the camera.
        rig: the calibration rig (pattern, plate, speakers).
        rig_to_cam0: pose of the rig, x_cam0 = R x_rig + t; None renders the empty background.
        rng: source of the sensor noise.
        noise_grey: standard deviation of the additive Gaussian sensor noise, grey levels.
        blur_sigma_px: standard deviation of the Gaussian blur (lens, defocus), pixels.
        scene: what else changes the light reaching the lens (an arm in front of the board,
            a highlight on it, its motion during the exposure: sim.mistakes), applied to the
            ideal float image (grey levels, unclipped) before the blur and the sensor.
        effects: the realistic lab's camera effects (sim.optics; the plate's bow is the
            rig's own, `rig.sag_m`).
        camera_key: which sensor's fixed pattern (the world's seed and the camera's index).
        noise_scale: multiplies the sensor-noise effect's shot and read noise (`noise_grey`
            is already scaled).

    Only the printed face (+Z side of the rig) shows the pattern; a camera behind the plate
    sees a uniform grey back. The first image of a camera also computes its pixel rays (about
    0.5 s at 1280 x 960, then cached); each image after that takes about 0.1 s.
    """
    background = _background(camera.width, camera.height)
    rays = _pixel_rays(camera)
    blur: np.ndarray | float = blur_sigma_px
    if rig_to_cam0 is None:
        image = background
    else:
        rig_to_cam = camera.cam0_to_cam.compose(rig_to_cam0)
        hits = _board_hits(rays, rig_to_cam, rig)
        plate = _interval_coverage(hits.X, hits.w_x, rig.plate_m[0], rig.plate_m[1])
        plate *= _interval_coverage(hits.Y, hits.w_y, rig.plate_m[2], rig.plate_m[3])
        face: np.ndarray
        if not _sees_front(rig_to_cam):
            face = np.full_like(hits.X, BACK_GREY)
        elif effects.has("lighting"):
            face = _lit_face(rig, hits, rays, rig_to_cam, camera, effects)
        else:
            face = _front_face(rig, hits)
        image = background + plate * (face - background)
        if effects.has("defocus"):
            blur = _defocus_sigma(rig, hits, camera, effects, blur_sigma_px)
    if scene is not None:
        image = scene(np.asarray(image, dtype=np.float32))
    if effects.has("vignetting"):
        image = image * _vignetting(camera)
    return exposed(blurred(image, blur), rng, noise_grey, effects, noise_scale, camera_key)


def _camera_key(camera: CameraModel) -> tuple:
    """Hashable key of everything that fixes a camera's pixel rays (not its pose)."""
    K = np.ascontiguousarray(camera.K, dtype=np.float64)
    dist = np.ascontiguousarray(camera.dist, dtype=np.float64)
    return camera.name, camera.width, camera.height, K.tobytes(), dist.tobytes()


def _pixel_rays(camera: CameraModel) -> _PixelRays:
    """The camera's pixel rays, computed once per camera (cached: many images per camera)."""
    return _cached_pixel_rays(_camera_key(camera))


@lru_cache(maxsize=8)
def _cached_pixel_rays(key: tuple) -> _PixelRays:
    """Undistort every pixel centre of a camera given by _camera_key (about 0.5 s at 1280 x 960)."""
    _, width, height, K_bytes, dist_bytes = key
    K = np.frombuffer(K_bytes, dtype=np.float64).reshape(3, 3)
    dist = np.frombuffer(dist_bytes, dtype=np.float64)
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)
    xy = cv2.undistortPoints(pixels, K, dist, criteria=criteria).reshape(height, width, 2)
    x, y = xy[..., 0], xy[..., 1]
    u_back, v_back = _distort_to_pixels(x, y, K, dist)
    valid = np.hypot(u_back - u, v_back - v) < _RAY_CHECK_PX  # False for NaN too
    x_v, x_u = np.gradient(x)
    y_v, y_u = np.gradient(y)
    x, y, x_u, x_v, y_u, y_v = (m.astype(np.float32) for m in (x, y, x_u, x_v, y_u, y_v))
    return _PixelRays(x, y, x_u, x_v, y_u, y_v, valid=valid)


def _vignetting(camera: CameraModel) -> np.ndarray:
    """The camera's cos^4 fall-off at every pixel (sim.sensor.cos4_falloff; cached)."""
    return _cached_vignetting(_camera_key(camera))


@lru_cache(maxsize=8)
def _cached_vignetting(key: tuple) -> np.ndarray:
    rays = _cached_pixel_rays(key)
    falloff = cos4_falloff(rays.x, rays.y)
    falloff.flags.writeable = False
    return falloff


def _distort_to_pixels(
    x: np.ndarray, y: np.ndarray, K: np.ndarray, dist: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (u, v) of normalized undistorted coordinates (x, y).

    The same model as cv2.projectPoints with coefficients (k1, k2, p1, p2, k3) (which, like
    cv2.undistortPoints, ignores any skew in K), written out in numpy because
    cv2.projectPoints takes seconds on a million points.
    """
    k1, k2, p1, p2, k3 = dist[:5]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    u = K[0, 0] * xd + K[0, 2]
    v = K[1, 1] * yd + K[1, 2]
    return u, v


def _sees_front(rig_to_cam: RigidTransform) -> bool:
    """True if the camera (at the origin of its frame) is on the printed (+Z) side of the rig."""
    normal = rig_to_cam.R[:, 2]
    return float(normal @ rig_to_cam.t) < 0.0


def _board_hits(rays: _PixelRays, rig_to_cam: RigidTransform, rig: Rig) -> _BoardHits:
    """Intersect every pixel ray with the rig's face and measure the pixels' footprints.

    With n the rig's Z axis and t its origin in the camera frame, the ray d = (x, y, 1) meets
    the plane at depth lambda = (n . t) / (n . d), and X = lambda (e_X . d) - e_X . t, which is
    the homography X = (g_X . d) / (n . d) with g_X = (n . t) e_X - (e_X . t) n (same for Y).
    A bowed face (rig.sag_m) at height h(X, Y) is met h / (n . d) further along the ray:
    X + h (e_X . d) / (n . d); two fixed-point steps from the plane (the bow's slope, under
    1 %, makes the second step's change micrometres). The footprints are the plane's.
    """
    e_x, e_y, normal = rig_to_cam.R.T
    n_t = float(normal @ rig_to_cam.t)
    g_x = n_t * e_x - float(e_x @ rig_to_cam.t) * normal
    g_y = n_t * e_y - float(e_y @ rig_to_cam.t) * normal
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        denom = _dot_ray(normal, rays)
        X = _dot_ray(g_x, rays) / denom
        Y = _dot_ray(g_y, rays) / denom
        w_x = _footprint(X, g_x, normal, denom, rays)
        w_y = _footprint(Y, g_y, normal, denom, rays)
        hit = rays.valid & (denom * np.float32(n_t) > 0.0)  # in front of the camera
        hit &= (np.abs(X) < _FAR_M) & (np.abs(Y) < _FAR_M) & (w_x < _FAR_M) & (w_y < _FAR_M)
        height = np.zeros_like(X)
        if rig.sag_m != 0.0:
            X0, Y0 = X, Y
            along_x, along_y = _dot_ray(e_x, rays) / denom, _dot_ray(e_y, rays) / denom
            for _ in range(2):
                height = np.where(hit, rig.bow_height_m(X, Y), np.float32(0.0))
                X, Y = X0 + height * along_x, Y0 + height * along_y
        depth = (np.float32(n_t) + height) / denom
    far = np.float32(_FAR_M)
    return _BoardHits(
        X=np.where(hit, X, far),
        Y=np.where(hit, Y, far),
        w_x=np.where(hit, np.maximum(w_x, np.float32(_MIN_FOOTPRINT_M)), np.float32(1.0)),
        w_y=np.where(hit, np.maximum(w_y, np.float32(_MIN_FOOTPRINT_M)), np.float32(1.0)),
        depth=np.where(hit, depth, np.float32(_FAR_M)),
        hit=hit,
    )


def _dot_ray(vector: np.ndarray, rays: _PixelRays) -> np.ndarray:
    """vector . (x, y, 1) for every pixel ray (float32 map)."""
    a, b, c = (np.float32(value) for value in vector)
    return a * rays.x + b * rays.y + c


def _footprint(
    coord: np.ndarray, g: np.ndarray, normal: np.ndarray, denom: np.ndarray, rays: _PixelRays
) -> np.ndarray:
    """Extent (metres) along one rig axis of each pixel's footprint on the board.

    coord = (g . d) / (n . d) has d(coord)/dx = (g_x - coord n_x) / (n . d) (same for y); the
    chain rule through the undistortion gives its change across one pixel in u and in v, and
    the footprint is their root sum of squares.
    """
    d_dx = (np.float32(g[0]) - coord * np.float32(normal[0])) / denom
    d_dy = (np.float32(g[1]) - coord * np.float32(normal[1])) / denom
    d_du = d_dx * rays.x_u + d_dy * rays.y_u
    d_dv = d_dx * rays.x_v + d_dy * rays.y_v
    return np.hypot(d_du, d_dv)


def _front_face(rig: Rig, hits: _BoardHits) -> np.ndarray:
    """Grey level of the printed face at each pixel's hit point: pattern and speakers."""
    dark = _dark_fraction(rig, hits)
    face = WHITE_GREY + dark * np.float32(DARK_GREY - WHITE_GREY)
    speakers = _speaker_coverage(rig, hits)
    return face + speakers * (np.float32(SPEAKER_GREY) - face)


def _lit_face(rig: Rig, hits: _BoardHits, rays: _PixelRays, rig_to_cam: RigidTransform,
              camera: CameraModel, effects: CameraEffects) -> np.ndarray:
    """The printed face under the lab's lamp (sim.optics.LightModel): its greys scaled by the
    light at each point over the plate's brightest light (the auto exposure keeps the
    brightest white at the print's stated grey, below saturation), plus the glossy print's
    specular highlight, a Gaussian on the board around where the camera sees the lamp's
    mirror image (the ray to the lamp mirrored in the board's plane; none when that point is
    behind the camera)."""
    light = effects.light
    normal, t = rig_to_cam.R[:, 2], rig_to_cam.t
    lamp = camera.cam0_to_cam.apply(np.asarray(light.lamp_m, dtype=np.float64)[None, :])[0]
    depth = np.where(hits.hit, hits.depth, np.float32(0.0))
    lit = light.irradiance(rays.x * depth, rays.y * depth, depth, normal, lamp)
    on_plate = hits.on_plate(rig)
    if not on_plate.any():
        return _front_face(rig, hits)
    face = _front_face(rig, hits) * (lit / lit[on_plate].max())
    mirrored = lamp - 2.0 * float(normal @ (lamp - t)) * normal
    n_m = float(normal @ mirrored)
    if n_m * float(normal @ t) <= 0.0:  # the mirror image's ray does not meet the board
        return face
    X_h, Y_h, _ = rig_to_cam.R.T @ (mirrored * float(normal @ t) / n_m - t)
    r2 = (hits.X - np.float32(X_h)) ** 2 + (hits.Y - np.float32(Y_h)) ** 2
    peak = np.float32(light.specular_peak * WHITE_GREY)
    return face + peak * np.exp(-r2 / np.float32(2 * light.specular_sigma_m**2))


def _defocus_sigma(rig: Rig, hits: _BoardHits, camera: CameraModel, effects: CameraEffects,
                   lens_sigma_px: float) -> np.ndarray:
    """Each pixel's blur (pixels of sigma): the lens's own and its depth's defocus, added in
    quadrature; pixels off the plate take the plate's median depth (they hold no corner, and
    the blur's range stays the plate's: sim.sensor.blurred interpolates across it)."""
    on_plate = hits.on_plate(rig)
    if not on_plate.any():
        return np.asarray(lens_sigma_px, dtype=np.float32)
    depth = np.where(on_plate, hits.depth, np.float32(np.median(hits.depth[on_plate])))
    defocus = effects.lens.blur_sigma_px(depth, float(camera.K[0, 0]))
    return np.sqrt(np.float32(lens_sigma_px**2) + defocus * defocus)


def _dark_fraction(rig: Rig, hits: _BoardHits) -> np.ndarray:
    """Fraction of each pixel's footprint covered by dark squares (0..1).

    Along one axis, P is the box-filtered indicator of the pattern's extent and Q the
    box-filtered square wave (+1 on even squares, -1 on odd ones) restricted to that extent;
    (P + Q) / 2 and (P - Q) / 2 are the fractions on even and odd squares, and a square is dark
    when both indices are even or both odd: dark = (P_X P_Y + Q_X Q_Y) / 2 (with the opposite
    convention the odd squares: (P_X P_Y - Q_X Q_Y) / 2).
    """
    s = rig.square_m
    p_x, q_x = _pattern_filters(hits.X, hits.w_x, s, rig.corners_x * s)
    p_y, q_y = _pattern_filters(hits.Y, hits.w_y, s, rig.corners_y * s)
    parity = 1.0 if rig.origin_square == "dark" else -1.0
    return 0.5 * (p_x * p_y + parity * q_x * q_y)


def _pattern_filters(
    coord: np.ndarray, width: np.ndarray, square_m: float, end_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Box filters (width `width`) along one axis of the pattern extent [-s, end] and of the
    square wave on it, as differences of their antiderivatives (exact for any width).

    The square wave (+1 on [0, s], -1 on [-s, 0], period 2 s) has the triangle wave
    T(c) = s - |c mod 2s - s| as antiderivative.
    """
    s = np.float32(square_m)
    half = np.float32(0.5) * width
    lo = np.clip(coord - half, -s, np.float32(end_m))
    hi = np.clip(coord + half, -s, np.float32(end_m))
    extent = (hi - lo) / width
    wave = (np.abs(np.mod(lo, 2 * s) - s) - np.abs(np.mod(hi, 2 * s) - s)) / width
    return extent, wave


def _interval_coverage(
    coord: np.ndarray, width: np.ndarray, lo_m: float, hi_m: float
) -> np.ndarray:
    """Box filter (width `width`) of the indicator of [lo_m, hi_m] along one axis (0..1)."""
    half = np.float32(0.5) * width
    lo, hi = np.float32(lo_m), np.float32(hi_m)
    return (np.clip(coord + half, lo, hi) - np.clip(coord - half, lo, hi)) / width


def _speaker_coverage(rig: Rig, hits: _BoardHits) -> np.ndarray:
    """Fraction of each pixel covered by a speaker disc (0..1), drawn at the speakers' (X, Y).

    The ramp across a disc's rim uses the mean footprint of the two axes: the rims only need
    to look right, unlike the checkerboard edges that carry the corner positions.
    """
    nearest_sq = np.full(hits.X.shape, np.inf, dtype=np.float32)
    for sx, sy in rig.speakers_m[:, :2]:
        dx = hits.X - np.float32(sx)
        dy = hits.Y - np.float32(sy)
        np.minimum(nearest_sq, dx * dx + dy * dy, out=nearest_sq)
    width = np.sqrt(np.float32(0.5) * (hits.w_x * hits.w_x + hits.w_y * hits.w_y))
    radius = np.float32(rig.speaker_diameter_m / 2)
    return np.clip((radius - np.sqrt(nearest_sq)) / width + np.float32(0.5), 0.0, 1.0)


@lru_cache(maxsize=8)
def _background(width: int, height: int) -> np.ndarray:
    """Smooth diagonal grey gradient (float32, read-only) behind the rig: a dim room."""
    darkest, brightest = BACKGROUND_GREY_RANGE
    ramp_u = np.linspace(0.0, 0.6, width, dtype=np.float32)
    ramp_v = np.linspace(0.0, 0.4, height, dtype=np.float32)
    image = np.float32(darkest) + np.float32(brightest - darkest) * (ramp_v[:, None] + ramp_u)
    image.flags.writeable = False
    return image
