"""What the image mistakes do to a camera's picture: an arm over the board, a specular
highlight, the board's motion during the exposure, MJPEG compression.

The first three act on the ideal float image before the lens blur and the sensor (they are in
front of the lens: sim.light's `scene` hook), MJPEG on the camera's 8-bit output. Pixel
coordinates are OpenCV's (u right, v down, pixel centres at integers).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..light import DARK_GREY

ARM_GREY = 28.0
"""Grey level of the arm and hand (a dark sleeve, darker than the print's dark squares)."""
GLARE_SPAN = 3.0
"""A highlight's peak over what it takes to saturate the darkest print at its radius."""
HIDDEN_DEPTH_PX = 1.0
"""A corner counts as hidden when it lies this far inside the arm's outline (the outline's
anti-aliased pixel and the lens blur leave it dark)."""
_FAR_PX = 1.0e4
"""Length of the arm beyond its hand: out of any image."""


def _pixel_grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float32)
    return u, v


@dataclass(frozen=True)
class Occluder:
    """An arm reaching over the board: a band of half-width `half_width_px` from far outside
    the image along `direction` (a unit vector, from the hand up the arm) to the hand at
    `hand_px`, which is a disc of radius `hand_radius_px`."""

    hand_px: tuple[float, float]
    direction: tuple[float, float]
    half_width_px: float
    hand_radius_px: float

    def distance(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Signed distance (pixels) of points from the arm's outline: < 0 inside."""
        du, dv = u - self.hand_px[0], v - self.hand_px[1]
        along = np.clip(du * self.direction[0] + dv * self.direction[1], 0.0, _FAR_PX)
        arm = np.hypot(du - along * self.direction[0], dv - along * self.direction[1])
        return np.minimum(arm - self.half_width_px, np.hypot(du, dv) - self.hand_radius_px)

    def covers(self, points_px: np.ndarray) -> np.ndarray:
        """Which points (n, 2) the arm hides: those a pixel or more inside its outline."""
        return self.distance(points_px[:, 0], points_px[:, 1]) <= -HIDDEN_DEPTH_PX

    def __call__(self, image: np.ndarray) -> np.ndarray:
        u, v = _pixel_grid(image.shape)
        alpha = np.clip(0.5 - self.distance(u, v), 0.0, 1.0)  # anti-aliased over one pixel
        return image + alpha * (np.float32(ARM_GREY) - image)


@dataclass(frozen=True)
class Glare:
    """A specular highlight: a Gaussian of light added at `centre_px`, bright enough to
    saturate even the print's dark squares within `radius_px` of its centre."""

    centre_px: tuple[float, float]
    radius_px: float

    def __call__(self, image: np.ndarray) -> np.ndarray:
        needed = 255.0 - DARK_GREY  # what saturates a dark square
        sigma = self.radius_px / np.sqrt(2.0 * np.log(GLARE_SPAN))
        u, v = _pixel_grid(image.shape)
        r2 = (u - self.centre_px[0]) ** 2 + (v - self.centre_px[1]) ** 2
        return image + np.float32(GLARE_SPAN * needed) * np.exp(-r2 / np.float32(2 * sigma**2))


@dataclass(frozen=True)
class MotionBlur:
    """The board moving during the exposure: a uniform linear blur of `length_px` pixels at
    `angle_deg` (from the image's u axis towards v)."""

    length_px: float
    angle_deg: float

    def kernel(self) -> np.ndarray:
        """The blur's kernel: the segment, area-sampled (bilinear splats of 16 points per
        pixel of length), summing to 1."""
        half = int(np.ceil(self.length_px / 2)) + 1
        k = np.zeros((2 * half + 1, 2 * half + 1), dtype=np.float64)
        a = np.radians(self.angle_deg)
        s = np.linspace(-self.length_px / 2, self.length_px / 2,
                        max(2, int(16 * self.length_px)))
        x, y = half + s * np.cos(a), half + s * np.sin(a)
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        fx, fy = x - x0, y - y0
        for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                          (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            np.add.at(k, (y0 + dy, x0 + dx), w)
        return k / k.sum()

    def __call__(self, image: np.ndarray) -> np.ndarray:
        return cv2.filter2D(image, -1, self.kernel().astype(np.float32),
                            borderType=cv2.BORDER_REFLECT)


def mjpeg(image: np.ndarray, quality: int) -> np.ndarray:
    """`image` (8-bit grey) as a camera delivering MJPEG hands it over: JPEG-encoded at
    `quality` and decoded again."""
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    decoded = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if ok else None
    if decoded is None:
        raise RuntimeError(f"OpenCV could not JPEG-encode and decode a {image.shape} image")
    return np.asarray(decoded)
