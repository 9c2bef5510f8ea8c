"""Every figure of a report, a study and `micam image`, drawn from small made-up inputs and
looked at through matplotlib's renderer as a reader would: no text cut off by the figure's
edge, no two texts on top of each other, ticks where they count things at whole numbers, a
legend for every colour and mark that needs one, and legends that cover no data.

Each test builds its figure from a few arrays (no calibration run), so they are fast; the
figures of a real calibration are checked in test_figures.py."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.text import Text
from matplotlib.transforms import Bbox

from calibration.figures.geometry import ArrayPicture, CameraMark, geometry_figure
from calibration.figures.maps import MapPanel, ScaleBar, acoustic_map_figure
from calibration.figures.residuals import (
    CornerResiduals,
    TofResiduals,
    corner_residual_figure,
    tof_residual_figure,
)
from calibration.figures.study import study_figure
from imaging.figures.recording_map import pixels_per_metre
from imaging.geometry import CameraView
from imaging.grid import PlaneGrid
from kernel.rigid import RigidTransform

TOUCH_PX = 0.5
"""How far (figure pixels) a box may reach past another before it counts as overlapping."""


def _drawn_texts(fig: Figure) -> list[tuple[Text, Bbox]]:
    """Every text the figure draws (ticks outside their axis's view are not drawn), with its
    box in figure pixels, after laying the figure out."""
    fig.draw_without_rendering()
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    undrawn: set[int] = set()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            slack = 1e-9 * max(abs(lo), abs(hi), 1.0)
            for tick in axis.get_major_ticks() + axis.get_minor_ticks():
                if not lo - slack <= tick.get_loc() <= hi + slack:
                    undrawn |= {id(tick.label1), id(tick.label2)}
    drawn = []
    for text in fig.findobj(Text):
        if id(text) in undrawn or not text.get_visible() or not text.get_text().strip():
            continue
        if text.axes is not None and not text.axes.get_visible():
            continue
        drawn.append((text, text.get_window_extent(renderer)))
    return drawn


def _shrunk(box: Bbox) -> Bbox:
    return Bbox.from_extents(box.x0 + TOUCH_PX, box.y0 + TOUCH_PX, box.x1 - TOUCH_PX,
                             box.y1 - TOUCH_PX)


def _rectangle(text: Text, box: Bbox) -> np.ndarray:
    """(4, 2) corners of a text's own (rotated) rectangle, less `TOUCH_PX` on each side: the
    rectangle whose axis-aligned box `box` is (its centre is the box's; its sides follow from
    W = w cos + h sin, H = w sin + h cos)."""
    angle = np.radians(text.get_rotation() % 180.0)
    c, s = abs(np.cos(angle)), abs(np.sin(angle))
    w, h = (np.linalg.solve([[c, s], [s, c]], [box.width, box.height])
            if abs(c - s) > 1e-6 else (box.width, box.height))
    w, h = max(w - 2 * TOUCH_PX, 0.0), max(h - 2 * TOUCH_PX, 0.0)
    along = np.array([np.cos(angle), np.sin(angle)])
    across = np.array([-along[1], along[0]])
    centre = np.array([box.x0 + box.x1, box.y0 + box.y1]) / 2
    return np.array([centre + a * w / 2 * along + b * h / 2 * across
                     for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two convex quadrilaterals (4, 2) overlap (no side of either separates them)."""
    for quad in (a, b):
        for k in range(4):
            edge = quad[(k + 1) % 4] - quad[k]
            normal = np.array([-edge[1], edge[0]])
            pa, pb = a @ normal, b @ normal
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


def assert_readable(fig: Figure) -> None:
    """No text reaches past the figure's edge, and no two texts overlap (rotated ones
    compared as the rotated rectangles they are)."""
    texts = _drawn_texts(fig)
    edge = fig.bbox
    cut = [t.get_text() for t, box in texts
           if box.x0 < edge.x0 - TOUCH_PX or box.x1 > edge.x1 + TOUCH_PX
           or box.y0 < edge.y0 - TOUCH_PX or box.y1 > edge.y1 + TOUCH_PX]
    assert not cut, f"cut off by the figure's edge: {cut}"
    quads = [(t.get_text(), _rectangle(t, box)) for t, box in texts]
    crowded = [(a, b) for (a, qa), (b, qb) in combinations(quads, 2) if _overlap(qa, qb)]
    assert not crowded, f"texts on top of each other: {crowded}"


def _tick_values(ax: Axes, which: str = "x") -> list[float]:
    """The major tick values drawn on an axis (inside its view)."""
    axis = ax.xaxis if which == "x" else ax.yaxis
    lo, hi = sorted(axis.get_view_interval())
    return [v for v in axis.get_majorticklocs() if lo <= v <= hi]


def _legend_labels(legend) -> list[str]:
    return [t.get_text() for t in legend.get_texts()]


def _study_rows(counts: tuple[int, ...]) -> list[dict]:
    return [{"n_sources": n, "trials": 3, "mean_error_m": 2e-3 / np.sqrt(n), "sem_m": 1e-5,
             "crlb_m": 1.2e-3 / np.sqrt(n), "efficiency": 1.6, "latency": "per_board",
             "joint_error_m": 4e-4 / np.sqrt(n), "joint_sem_m": 1e-6} for n in counts]


def test_study_ticks_are_plain_numbers_that_do_not_overlap() -> None:
    """Source counts of less than two decades: matplotlib's own log labels ("3x10^0",
    "4x10^0", ...) ran into each other there."""
    fig = study_figure([{"band_m": band, "rows": _study_rows((3, 12, 36))}
                        for band in ((0.6, 1.0), (1.0, 1.4), (1.5, 2.0))])
    assert_readable(fig)
    for ax in (a for a in fig.axes if (a.get_gid() or "").startswith("band-")):
        labels = [t.get_text() for t in ax.get_xticklabels()
                  if t.get_text() and ax.get_xlim()[0] <= t.get_position()[0] <= ax.get_xlim()[1]]
        assert len(labels) >= 2 and all(label.isdigit() for label in labels), labels
        assert ax.get_xlabel() == "sources" and "mm" in fig.axes[0].get_ylabel()
    legend = _legend_labels(fig.legends[0])
    assert {"camera frozen", "joint fit", "bound (frozen model)"} <= set(legend)


def _tof_residuals(n_poses: int, boards: int) -> TofResiduals:
    """Residuals of 40 microphones on `boards` boards, 3 sources per pose."""
    rng = np.random.default_rng(4)
    mics = 40
    sources = 3 * n_poses
    return TofResiduals(rng.normal(0.0, 1e-8, (sources, mics)),
                        np.repeat(np.arange(n_poses), 3),
                        rng.normal(0.0, 0.3, (sources, 3)) + [0.0, 0.0, 1.0],
                        rng.normal(0.0, 0.1, (mics, 3)), np.arange(mics),
                        tuple(f"1600{k * boards // mics}" for k in range(mics)))


@pytest.mark.slow  # about 1.3 s: the figure is laid out twice (the board legend's height)
def test_tof_residuals_count_poses_in_whole_numbers_and_name_every_board() -> None:
    data = _tof_residuals(n_poses=16, boards=9)  # 0-15: matplotlib ticked 2.5, 7.5, ...
    fig = tof_residual_figure(data)
    assert_readable(fig)
    per_pose = next(ax for ax in fig.axes if ax.get_title() == "RMS per pose")
    ticks = _tick_values(per_pose)
    assert len(ticks) >= 3 and all(float(t).is_integer() for t in ticks), ticks
    per_mic = next(ax for ax in fig.axes if ax.get_title().startswith("RMS per microphone"))
    legend = per_mic.get_legend()
    assert legend is not None and legend.get_gid() == "board-legend"
    assert sorted(_legend_labels(legend)) == sorted(set(data.boards))
    colours = {tuple(h.get_facecolor()) for h in legend.legend_handles}
    assert len(colours) == 9, "nine boards, nine colours"
    bars = {tuple(p.get_facecolor()) for p in per_mic.patches if isinstance(p, Rectangle)}
    assert bars == colours  # the legend's colours are the bars'
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    box = legend.get_window_extent(renderer)
    covered = [p for p in per_mic.patches if p.get_height() > 0
               and _shrunk(p.get_window_extent(renderer)).overlaps(box)]
    assert not covered, "the board legend covers bars"
    for ax in fig.axes:  # no legend over a panel's points but the boards'
        assert ax.get_legend() is None or ax is per_mic
    assert set(_legend_labels(fig.legends[0])) == {"± RMS per bin",
                                                   "normal distribution of the same RMS"}


def _corners(n: int) -> list[CornerResiduals]:
    rng = np.random.default_rng(2)
    return [CornerResiduals(f"cam{k}", rng.normal(0.0, 0.1, (60, 2)),
                            rng.uniform(0.0, [1280.0, 960.0], (60, 2)),
                            np.array([640.0, 480.0]), 5) for k in range(n)]


@pytest.mark.parametrize("cameras", [3, 4])
def test_corner_residuals_keep_every_title_and_label_inside(cameras: int) -> None:
    """Three cameras side by side cut the right panel's title and label off; a fourth starts
    a new pair of rows."""
    fig = corner_residual_figure(_corners(cameras))
    assert_readable(fig)
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 2 * cameras
    titles = [ax.get_title() for ax in visible]
    assert all(any(title.startswith(f"cam{k}:") for title in titles) for k in range(cameras))
    assert all(ax.get_legend() is None for ax in visible)  # none over the points
    assert {ax.get_xlabel() for ax in visible} == {"dx (px)", "radius (px)"}
    assert any("RMS radius" in t for t in _legend_labels(fig.legends[0]))
    assert "RMS per bin" in _legend_labels(fig.legends[0])


def _flat_array_picture() -> ArrayPicture:
    """An imported lab's flat array, 0.6 m wide, facing the camera, with the speakers of six
    poses 0.5-0.9 m in front: the scene view's legend sat on its microphones."""
    rng = np.random.default_rng(5)
    mics = np.column_stack([rng.uniform(-0.3, 0.3, 48), rng.uniform(-0.3, 0.3, 48),
                            rng.normal(-0.02, 0.003, 48)])
    sources = np.column_stack([rng.uniform(-0.2, 0.2, 36), rng.uniform(-0.1, 0.1, 36),
                               rng.uniform(0.5, 0.9, 36)])
    cov = np.broadcast_to(np.diag([2e-5, 2e-5, 6e-5]) ** 2, (48, 3, 3)).copy()
    camera = CameraMark("camera", np.zeros(3), np.array([0.0, 0.0, 1.0]))
    return ArrayPicture(mics + rng.normal(0.0, 2e-5, mics.shape), cov, mics,
                        "simulated truth", (camera,), sources)


def test_geometry_legend_covers_no_view() -> None:
    fig = geometry_figure(_flat_array_picture())
    assert_readable(fig)
    scene = next(ax for ax in fig.axes if ax.get_gid() == "view-scene")
    assert scene.get_legend() is None
    legend = fig.legends[0]
    labels = _legend_labels(legend)
    assert {"microphone (scene view)", "speaker position (scene view)",
            "camera and its optical axis"} <= set(labels)
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    box = legend.get_window_extent(renderer)
    assert not any(box.overlaps(ax.get_window_extent(renderer)) for ax in fig.axes)
    assert scene.get_aspect() == 1.0
    assert scene.get_xlabel() == "x (m)" and scene.get_ylabel() == "z (m, forward)"


def _pinhole(focal_px: float, width: int = 160, height: int = 120) -> CameraView:
    K = np.array([[focal_px, 0.0, width / 2], [0.0, focal_px, height / 2], [0.0, 0.0, 1.0]])
    return CameraView("cam0", width, height, K, np.zeros(5), RigidTransform.identity())


def test_image_scale_of_a_plane_facing_the_camera_is_focal_length_over_distance() -> None:
    view = _pinhole(focal_px=800.0)
    facing = PlaneGrid.xy_plane((-0.1, 0.1), (-0.1, 0.1), 0.5, 0.01)
    assert pixels_per_metre(view, facing, np.array([0.0, 0.0, 0.5])) == pytest.approx(1600.0,
                                                                                      rel=1e-6)
    # Tilted by 60 deg about y: foreshortened by cos 60 along u, the geometric mean sqrt(0.5).
    a = np.radians(60.0)
    tilted = PlaneGrid.on_plane(np.array([0.0, 0.0, 0.5]), np.array([np.cos(a), 0.0, np.sin(a)]),
                                np.array([0.0, 1.0, 0.0]), (-0.1, 0.1), (-0.1, 0.1), 0.01)
    assert pixels_per_metre(view, tilted, np.array([0.0, 0.0, 0.5]), step_m=1e-4) == \
        pytest.approx(1600.0 * np.sqrt(0.5), rel=1e-3)


def test_map_has_a_colour_bar_a_scale_bar_and_a_legend_for_its_marks() -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(60, 120, (120, 160)).astype(np.uint8)
    yy, xx = np.mgrid[0:120, 0:160]
    layer = np.exp(-((xx - 70.0) ** 2 + (yy - 50.0) ** 2) / 200.0)
    speakers = np.array([[70.0, 50.0], [120.0, 90.0]])
    panels = [MapPanel("delay-and-sum", layer),
              MapPanel("CLEAN-SC", None, np.array([[70.0, 50.0], [100.0, 30.0]]),
                       np.array([1.0, 0.2]))]
    fig = acoustic_map_figure(image, panels, speakers, 0, 15.0, "a map",
                              ScaleBar(pixels_per_m=400.0, where="on the rig plane"))
    assert_readable(fig)
    bar = next(ax for ax in fig.axes if ax.get_gid() == "colour-bar")
    assert "dB" in bar.get_ylabel() and bar.get_ylim() == pytest.approx((-15.0, 0.0))
    labels = _legend_labels(next(lg for lg in fig.legends if lg.get_gid() == "map-legend"))
    assert labels == ["speaker, where the camera places it", "the speaker that plays",
                      "CLEAN-SC component (colour and size: its level)"]
    for k in (0, 1):
        ax = next(a for a in fig.axes if a.get_gid() == f"map-{k}")
        scale = next(a for a in ax.artists if a.get_gid() == "scale-bar")
        # 20 % of 160 px at 400 px/m is 80 mm: the bar is 50 mm, 20 image pixels long
        texts = [t.get_text() for t in scale.findobj(Text)]
        assert texts == ["50 mm on the rig plane"]
        line = next(c for c in scale.findobj() if hasattr(c, "get_xdata") and c is not scale)
        assert np.ptp(line.get_xdata()) == pytest.approx(0.05 * 400.0)
