"""Mistakes of the capture's images, found in the images themselves: a board half hidden (an
arm in front of it), blurred by motion, in glare, and cameras that deliver MJPEG.

Each is judged against the same camera's other views where it can be (the sharpness of its
edges, the strength of its corners), so that another lab's lens or exposure does not move the
thresholds; saturation and JPEG's quantised blocks are absent from raw, well-exposed frames
whatever the lab. A view whose corners cannot be trusted (blurred, or in glare) is left out of
the camera calibration, which is then computed without it; an image where the board was not
found is named when the reason shows (a hidden part, a highlight, corners blurred too weak to
find); MJPEG, which moves every corner of a camera a little, is noted.

The thresholds come from the measures (calibration.camera.image_measures) on clean and mistaken
realistic sessions; each says its figures (also in docs/calibration.md, "Mistakes of the
capture").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .._cores import default_workers
from .corners import Checkerboard
from ..memo import LruMemo
from .image_measures import (
    edge_sharpness,
    jpeg_quantisation,
    saturated_reach,
    saturated_share,
    x_corner_response,
    x_corners,
)
from ..result import Finding

BLUR_RATIO = 0.6
"""A view whose edge sharpness (`edge_sharpness`) is below this share of its camera's median
view is blurred by motion. Clean realistic views lie at 0.81-1.17 of their camera's median;
a motion over 8 px (the simulated world's shortest default) takes about 1/8 px^-1 against
0.3-0.45, below 0.5; over 22 px, 0.2."""

GLARE_SHARE = 0.002
"""A board with more than this share of the pixels inside its corners' hull saturated is in
glare: clean realistic boards have none (their white squares peak at 220 of 255); a highlight
of the simulated world's smallest default disc saturates several per cent."""

MJPEG_QUANTISATION = 0.4
"""A camera whose median view's `jpeg_quantisation` exceeds this delivers JPEG-compressed
frames: raw realistic frames (sensor noise at gain 16) lie at 0.02 at most, the ideal world's
low-noise ones at 0.14 at most; MJPEG at quality 95 at 0.66, 90 at 0.83, 70 at 0.98. (The
block seams measured before fell to 1.02 times the steps elsewhere at quality 90 and gain
16, where raw frames lay at 0.99-1.01: the noise hid them.)"""

X_CORNER_LEVEL = 0.3
"""An X-corner counts as visible in an image where the board was not found when its
response (`x_corner_response`) reaches this share of the camera's median response at the
corners of its found views."""

VISIBLE_SHARE = 0.9
"""An image with fewer of the board's corners visible than this share, none of them near the
image's edge, shows a board partly hidden (a board merely missed shows them all). In glare,
the corners within a square of its saturated pixels (`saturated_reach`) count as visible: a
highlight alone left 40-48 of 54 visible with a reach of 14-30 squares (58-72 together); a
board 40 % hidden and in glare, 32 with 13 (45)."""

EDGE_MARGIN_SQUARES = 1.5
"""A visible X-corner within this many squares of the image's edge means the board ran off
the image: a framing, not a hidden board, and not named."""

MIN_VISIBLE = 3
"""Fewest visible X-corners that show a board at all."""

WEAK_X_CORNER_LEVEL = 0.07
"""An image where the board was not found and fewer than `MIN_VISIBLE` X-corners reach
`X_CORNER_LEVEL` shows a blurred board when `MIN_BLURRED_VISIBLE` reach this share of the
camera's median response: a motion of 12.6 px (with a highlight on it, which stopped the
detector) left 0 corners above 0.15 of the median, 23 above 0.07. On the found views of
four realistic 20-pose sessions no peak off the board reached 0.05 (the `x_shape` test
takes out the noise's)."""

MIN_BLURRED_VISIBLE = 6
"""Fewest weak X-corners (`WEAK_X_CORNER_LEVEL`) that show a blurred board: a 2 x 3 patch of
the grid, more than a stray pattern in the background gives."""

MIN_VIEWS_FOR_BLUR = 3
"""Fewest found views of a camera for judging their sharpness against its median (of three
views, one blurred leaves the median a sharp one's)."""


@dataclass(frozen=True)
class ViewImage:
    """A view to check: its camera and step, and its corners (None: the board was not found)."""

    camera: str
    step: str
    corners_px: np.ndarray | None


@dataclass(frozen=True)
class ImageVerdict:
    """What the image checks found.

    Attributes:
        findings: the mistakes, cameras and poses named.
        left_out: views (camera, step) whose corners are not to be used, with the reason.
    """

    findings: list[Finding]
    left_out: dict[tuple[str, str], str]


@dataclass(frozen=True)
class _Measured:
    view: ViewImage
    sharpness: float
    saturated: float
    jpeg_quantisation: float
    response: float
    spacing_px: float


ImageCheckMemo = LruMemo[tuple, tuple[Any]]
"""What the image checks measured, by the image's SHA-256 and all else the measure depends
on: (sha, board) for a found board's measures, (sha, board, the camera's typical corner
response and spacing) for an image without a board (the list of its findings); each value in
a 1-tuple. A worker keeps one, so that its live jobs read each image once."""


def check_images(views: list[ViewImage], read: Callable[[tuple[str, str]], np.ndarray],
                 board: Checkerboard, hashes: dict[tuple[str, str], str] | None = None,
                 memo: ImageCheckMemo | None = None) -> ImageVerdict:
    """The image mistakes of `views` (every image of the cameras), each image read by `read`
    (camera, step). Images of a camera without a found view are not judged (nothing tells
    how its board's corners look). With a `memo` and the images' SHA-256 (`hashes`, by
    (camera, step)), what was measured before is not measured again."""

    def remembered(view: ViewImage, inputs: tuple, measure: Callable[[np.ndarray], Any]) -> Any:
        key = (view.camera, view.step)
        entry = None if memo is None or hashes is None else (hashes[key], board, *inputs)
        if memo is not None and entry is not None and (known := memo.get(entry)) is not None:
            return known[0]
        value = measure(read(key))
        if memo is not None and entry is not None:
            memo.put(entry, (value,))
        return value

    found = [v for v in views if v.corners_px is not None]
    with ThreadPoolExecutor(default_workers()) as pool:
        measured: list[_Measured] = list(pool.map(
            lambda v: replace(remembered(v, (), lambda image: _measure(v, image, board)),
                              view=v), found))
    findings: list[Finding] = []
    left_out: dict[tuple[str, str], str] = {}
    by_camera: dict[str, list[_Measured]] = {}
    for m in measured:
        by_camera.setdefault(m.view.camera, []).append(m)
    jpeg = []
    for camera, ms in by_camera.items():
        typical = float(np.median([m.sharpness for m in ms]))
        for m in ms:
            key = (camera, m.view.step)
            if m.saturated > GLARE_SHARE:
                left_out[key] = "in glare"
                findings.append(_glare(m.view, m.saturated))
            elif len(ms) >= MIN_VIEWS_FOR_BLUR and m.sharpness < BLUR_RATIO * typical:
                left_out[key] = "blurred by motion"
                findings.append(Finding(
                    kind="motion-blur", action="left out", cameras=[camera],
                    poses=[m.view.step],
                    evidence=f"the board was blurred by motion at {m.view.step} in {camera}: "
                             f"its edges rise over {1 / m.sharpness:.1f} px against "
                             f"{1 / typical:.1f} px in {camera}'s other views",
                    advice="that view was left out of the camera calibration; hold the rig "
                           "still while the cameras expose (or shorten the exposure)"))
        quantised = float(np.median([m.jpeg_quantisation for m in ms]))
        if quantised > MJPEG_QUANTISATION:
            jpeg.append((camera, quantised))
    if jpeg:
        names = [c for c, _ in jpeg]
        findings.append(Finding(
            kind="mjpeg", action="noted", cameras=names,
            evidence=f"{_join(names)} deliver{'s' if len(names) == 1 else ''} JPEG-compressed "
                     "frames: the DCT of their 8 x 8 blocks lies on multiples of JPEG's steps "
                     "(quantisation "
                     f"{_join(f'{q:.2f}' for _, q in jpeg)} of 1; raw frames: near 0); the "
                     "compression moves the corners",
            advice="the views were used; set the cameras to uncompressed frames (YUYV) for "
                   "the next capture"))
    reference = {c: (float(np.median([m.response for m in ms])),
                     float(np.median([m.spacing_px for m in ms])))
                 for c, ms in by_camera.items()}
    missed = [v for v in views if v.corners_px is None and v.camera in reference]
    with ThreadPoolExecutor(default_workers()) as pool:
        judged = list(pool.map(lambda v: remembered(
            v, reference[v.camera], lambda image: _missed(v, image, board,
                                                          *reference[v.camera])), missed))
    for view, reasons in zip(missed, judged, strict=True):
        if reasons:
            findings.extend(reasons)
            left_out[(view.camera, view.step)] = " and ".join(
                f.kind.replace("-", " ") for f in reasons)
    return ImageVerdict(findings, left_out)


def _measure(view: ViewImage, image: np.ndarray, board: Checkerboard) -> _Measured:
    corners = view.corners_px
    assert corners is not None
    grid = corners.reshape(board.corners_y, board.corners_x, 2)
    spacing = float(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=-1)))
    # the response on the board and a square around it only: on the whole 1280 x 960 image
    # it took 15 ms, more than reading the image (10 ms)
    low = np.maximum(np.floor(corners.min(axis=0) - spacing), 0).astype(int)
    high = np.ceil(corners.max(axis=0) + spacing).astype(int)
    response = x_corner_response(image[low[1]:high[1] + 1, low[0]:high[0] + 1])
    at = np.round(corners).astype(int) - low
    return _Measured(view, edge_sharpness(image, corners, board),
                     saturated_share(image, corners), jpeg_quantisation(image),
                     float(np.median(response[at[:, 1], at[:, 0]])), spacing)


def _missed(view: ViewImage, image: np.ndarray, board: Checkerboard, response: float,
            spacing_px: float) -> list[Finding]:
    """The reasons the board was not found in an image, where the image shows one (none:
    an empty list)."""
    visible = x_corners(image, X_CORNER_LEVEL * response, spacing_px)
    if len(visible) < MIN_VISIBLE:
        return _blurred(view, image, response, spacing_px)
    height, width = image.shape[:2]
    margin = EDGE_MARGIN_SQUARES * spacing_px
    near_edge = np.any((visible < margin) | (visible > np.array([width, height]) - 1 - margin))
    saturated = saturated_share(image, visible)
    glare = [_glare(view, saturated)] if saturated > GLARE_SHARE else []
    # the corners a highlight hides are not hidden by anything in front of the board
    glared = saturated_reach(image, spacing_px) if glare else 0.0
    if near_edge or len(visible) + glared >= VISIBLE_SHARE * board.n_corners:
        return glare
    beside = (f", {glared:.0f} more within a square of the glare's saturated pixels"
              if glare else "")
    return [*glare, Finding(
        kind="hidden-board", action="left out", cameras=[view.camera], poses=[view.step],
        evidence=f"the board was half hidden at {view.step} in {view.camera}: "
                 f"{len(visible)} of its {board.n_corners} corners visible{beside}, none near "
                 "the image's edge, and the board not found",
        advice=f"that view was left out; keep the whole board in view of {view.camera} "
               "(nothing in front of it) while the cameras expose")]


def _blurred(view: ViewImage, image: np.ndarray, response: float, spacing_px: float
             ) -> list[Finding]:
    """A board not found whose X-corners all respond weakly (`WEAK_X_CORNER_LEVEL`): blurred,
    and in glare as well when a highlight saturates their hull."""
    weak = x_corners(image, WEAK_X_CORNER_LEVEL * response, spacing_px)
    if len(weak) < MIN_BLURRED_VISIBLE:
        return []
    at = weak.astype(int)
    strongest = float(np.max(x_corner_response(image)[at[:, 1], at[:, 0]])) / response
    blurred = Finding(
        kind="motion-blur", action="left out", cameras=[view.camera], poses=[view.step],
        evidence=f"the board was blurred at {view.step} in {view.camera}, too much to be "
                 f"found: {len(weak)} of its corners show, the strongest at "
                 f"{strongest:.2f} of the response of {view.camera}'s other views",
        advice="that view was left out; hold the rig still while the cameras expose (or "
               "shorten the exposure), and check the focus")
    saturated = saturated_share(image, weak)
    return [blurred, _glare(view, saturated)] if saturated > GLARE_SHARE else [blurred]


def _glare(view: ViewImage, saturated: float) -> Finding:
    return Finding(
        kind="glare", action="left out", cameras=[view.camera], poses=[view.step],
        evidence=f"the board was in glare at {view.step} in {view.camera}: {saturated:.1%} of "
                 "the board's pixels saturated",
        advice="that view was left out; turn the board or the lamp so that no highlight "
               "falls on it (a matte print), or lower the exposure")


def _join(items: Iterable[str]) -> str:
    names = list(items)
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
