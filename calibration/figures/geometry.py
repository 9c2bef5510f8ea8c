"""The calibrated array in three equal-aspect orthographic views, with its errors made visible.

Front (x, y: as camera 0 sees it, y down), top (x, z: z forward, up the page) and side (z, y)
views in millimetres of the camera-0 frame, and a fourth, top view of the whole scene in
metres (array, cameras, every speaker position). Against a reference (the simulated truth, or
the prior geometry rigidly fitted to the result) each microphone is drawn at its reference
position with its error vector magnified by a stated factor, and the 95 % ellipse of its
calibrated uncertainty (the projection of its 3x3 covariance into the view) magnified by the
same factor and centred on the reference: an arrow tip outside its ellipse is an error larger
than the calibration claims. When the uncertainty is so much larger than the errors that the
ellipses would cover the array, they get a smaller factor of their own, stated in the legend,
and the title counts the errors inside their 95 % ellipsoids instead. Without a reference the
ellipses are centred on the estimates.
Every camera is drawn (position and optical axis) and labelled beside its marker where the
label overlaps no other; cameras that coincide in a view share one label, and a camera the
calibration could not place is drawn hollow from the reference when it has one, or named in
the title.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.collections import EllipseCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Ellipse
from matplotlib.ticker import MaxNLocator
from matplotlib.transforms import Bbox

from .style import MINUS, PAGE_IN, PALETTE, TIMES, new_figure, nice_factor, styled

CHI2_95_2D = 5.991
"""Squared radius of the 95 % ellipse of a 2-D normal distribution, in standard deviations."""
VECTOR_SHARE = 0.12
"""The largest magnified error vector spans this fraction of the array's extent."""
ELLIPSE_SHARE = 0.06
"""At most this fraction of the array's extent for the median magnified ellipse radius: when
the errors' factor would draw them larger, the ellipses get a smaller factor of their own."""
CHI2_95_3D = 7.815
"""Squared Mahalanobis radius of the 95 % ellipsoid of a 3-D normal distribution."""


@dataclass(frozen=True)
class CameraMark:
    """A camera to draw: its centre and optical axis (unit vector) in the camera-0 frame."""

    name: str
    centre_m: np.ndarray
    axis: np.ndarray
    calibrated: bool = True


@dataclass(frozen=True)
class ArrayPicture:
    """What the geometry figure shows.

    Attributes:
        positions_m: (M, 3) calibrated microphone positions, camera-0 frame.
        covariance_m2: (M, 3, 3) their covariances (NaN where unknown), or None.
        reference_m: (M, 3) reference positions (truth, or a fitted prior), or None.
        reference_label: what the reference is ("simulated truth", ...).
        cameras: the cameras (calibrated ones from the result, others from the reference).
        sources_m: (N, 3) speaker positions for the scene view, or None.
        missing: names of cameras that could not be drawn, with the reason.
    """

    positions_m: np.ndarray
    covariance_m2: np.ndarray | None = None
    reference_m: np.ndarray | None = None
    reference_label: str = "reference"
    cameras: tuple[CameraMark, ...] = ()
    sources_m: np.ndarray | None = None
    missing: tuple[str, ...] = ()


VIEWS = (("front, as camera 0 sees it", 0, 1), ("top", 0, 2), ("side", 2, 1))
"""(title, horizontal axis, vertical axis) of the three array views; y points down."""
AXIS_NAMES = "xyz"


def _extent(points: np.ndarray) -> float:
    """The largest side of the bounding box of points (N, k), NaN rows ignored."""
    return float(np.max(np.nanmax(points, axis=0) - np.nanmin(points, axis=0)))


@dataclass(frozen=True)
class Magnification:
    """How much errors and uncertainty ellipses are magnified, and the errors (M, 3)."""

    errors: float
    ellipses: float
    error_m: np.ndarray | None


def _radius95(cov: np.ndarray) -> np.ndarray:
    """(M,) the largest semi-axis of each 95 % 2-D ellipse a view can show, metres."""
    with np.errstate(invalid="ignore"):
        return np.sqrt(CHI2_95_2D * np.linalg.eigvalsh(cov)[:, -1])


def _magnification(picture: ArrayPicture, extent: float) -> Magnification:
    """One factor for both (module docstring), unless the ellipses would then cover the
    array: they get their own, smaller factor (`ELLIPSE_SHARE`), stated in the legend."""
    errors = (None if picture.reference_m is None
              else picture.positions_m - picture.reference_m)
    largest = np.nanmax(np.linalg.norm(errors, axis=1)) if errors is not None else 0.0
    radius = np.nan
    if picture.covariance_m2 is not None:
        ok = np.all(np.isfinite(picture.covariance_m2.reshape(len(picture.covariance_m2), -1)),
                    axis=1)
        radius = float(np.median(_radius95(picture.covariance_m2[ok]))) if ok.any() else np.nan
    ellipses = (nice_factor(ELLIPSE_SHARE * extent / radius) if np.isfinite(radius) and radius > 0
                else np.inf)
    if largest > 0:
        vectors = nice_factor(VECTOR_SHARE * extent / largest)
        return Magnification(vectors, min(vectors, ellipses), errors)
    common = ellipses if np.isfinite(ellipses) else 1.0
    return Magnification(common, common, None if largest == 0 else errors)


def inside_ellipsoids(errors: np.ndarray, covariance: np.ndarray | None
                      ) -> tuple[int, int] | None:
    """(how many, of how many) errors (M, 3) lie inside the 95 % ellipsoid of their
    covariance (M, 3, 3); microphones without a finite covariance are not counted."""
    if covariance is None:
        return None
    ok = np.all(np.isfinite(covariance.reshape(len(covariance), -1)), axis=1) & np.all(
        np.isfinite(errors), axis=1)
    if not ok.any():
        return None
    e = errors[ok]
    d2 = np.einsum("mi,mi->m", e, np.linalg.solve(covariance[ok], e[..., None])[..., 0])
    return int(np.sum(d2 <= CHI2_95_3D)), int(ok.sum())


def _ellipses(cov: np.ndarray, i: int, j: int, factor: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Widths, heights and angles (deg) of the 95 % ellipses of covariances (M, 3, 3) in the
    (i, j) view, magnified by `factor`, in the units of cov's square root."""
    sub = cov[:, [i, j]][:, :, [i, j]]
    values, vectors = np.linalg.eigh(sub)
    radii = factor * np.sqrt(CHI2_95_2D * np.clip(values, 0, None))
    angles = np.degrees(np.arctan2(vectors[:, 1, 1], vectors[:, 0, 1]))
    return 2 * radii[:, 1], 2 * radii[:, 0], angles


LABEL_OFFSETS_PT = ((0, 7), (0, -9), (9, 0), (-9, 0), (8, 7), (-8, 7), (8, -9), (-8, -9),
                    (0, 18), (0, -20), (22, 0), (-22, 0))
"""Candidate offsets (points) of a camera label from its marker, tried in this order."""


def camera_groups(cameras: tuple[CameraMark, ...], i: int, j: int, close_mm: float
                  ) -> list[list[CameraMark]]:
    """Cameras that lie within close_mm of each other in the (i, j) view, grouped (they share
    one label)."""
    groups: list[list[CameraMark]] = []
    for cam in cameras:
        for group in groups:
            if np.hypot(*(1e3 * (cam.centre_m - group[0].centre_m))[[i, j]]) < close_mm:
                group.append(cam)
                break
        else:
            groups.append([cam])
    return groups


def _label_cameras(ax: Axes, cameras: tuple[CameraMark, ...], i: int, j: int,
                   close_mm: float) -> None:
    """One label per group of coinciding cameras, beside its marker: the first of
    `LABEL_OFFSETS_PT` whose box stays inside the axes and overlaps no label placed before
    (measured on the drawn figure; the last candidate if none does), on a white box over the
    microphones."""
    frame = ax.get_window_extent()
    placed: list[Bbox] = []
    for group in camera_groups(cameras, i, j, close_mm):
        text = ", ".join(c.name for c in group)
        anchor = 1e3 * group[0].centre_m
        for n, (dx, dy) in enumerate(LABEL_OFFSETS_PT):
            label = ax.annotate(
                text, xy=(anchor[i], anchor[j]), xytext=(dx, dy), textcoords="offset points",
                ha="center" if dx == 0 else ("left" if dx > 0 else "right"),
                va="center" if dy == 0 else ("bottom" if dy > 0 else "top"), fontsize=7,
                gid="camera-label", zorder=6,
                bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85})
            label.set_in_layout(False)
            box = label.get_window_extent()
            inside = (frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0
                      and box.y1 <= frame.y1)
            if n + 1 == len(LABEL_OFFSETS_PT) or (
                    inside and not any(box.overlaps(other) for other in placed)):
                placed.append(box)
                break
            label.remove()


def _draw_view(ax: Axes, picture: ArrayPicture, i: int, j: int, scale: Magnification
               ) -> None:
    """One orthographic view of the array in millimetres."""
    est = 1e3 * picture.positions_m
    base = 1e3 * picture.reference_m if picture.reference_m is not None else est
    extent = _extent(est[:, [i, j]])
    ax.scatter(base[:, i], base[:, j], s=9, facecolors="none", edgecolors="0.35",
               linewidths=0.5, zorder=2)
    if picture.covariance_m2 is not None:
        cov = 1e6 * picture.covariance_m2
        ok = np.all(np.isfinite(cov.reshape(len(cov), -1)), axis=1)
        if ok.any():
            w, h, a = _ellipses(cov[ok], i, j, scale.ellipses)
            ax.add_collection(EllipseCollection(
                w, h, a, units="xy", offsets=base[ok][:, [i, j]], offset_transform=ax.transData,
                facecolors=PALETTE[5], alpha=0.25, edgecolors="none", zorder=1))
    if scale.error_m is not None:
        e = 1e3 * scale.errors * scale.error_m
        ax.quiver(base[:, i], base[:, j], e[:, i], e[:, j], angles="xy", scale_units="xy",
                  scale=1.0, color=PALETTE[1], width=0.004, headwidth=3, headlength=3.5,
                  zorder=3)
    for cam in picture.cameras:
        c = 1e3 * cam.centre_m
        tip = c + 0.22 * extent * np.asarray(cam.axis)  # the same in the limits below
        ax.plot([c[i], tip[i]], [c[j], tip[j]], color="k", lw=0.7, zorder=4)
        ax.plot(c[i], c[j], "s", ms=4, mec="k", mfc="k" if cam.calibrated else "white",
                zorder=5)
    ax.set_aspect("equal", adjustable="box")
    ends = [1e3 * c.centre_m + f * 0.22 * extent * np.asarray(c.axis)
            for c in picture.cameras for f in (0.0, 1.0)]
    points = np.vstack([est[:, [i, j]], *[e[[i, j]] for e in ends]])
    lo = np.nanmin(points, axis=0) - 0.1 * extent
    hi = np.nanmax(points, axis=0) + 0.1 * extent
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_xlabel(f"{AXIS_NAMES[i]} (mm)")
    ax.set_ylabel(f"{AXIS_NAMES[j]} (mm)")
    if j == 1:
        ax.invert_yaxis()  # camera y points down


def _draw_scene(ax: Axes, picture: ArrayPicture) -> None:
    """Top view (x, z) of the array, the cameras and the speaker positions, in metres."""
    est = picture.positions_m
    ax.scatter(est[:, 0], est[:, 2], s=3, color=PALETTE[0], label="microphones", zorder=2)
    if picture.sources_m is not None and len(picture.sources_m):
        src = picture.sources_m
        ax.scatter(src[:, 0], src[:, 2], s=3, color=PALETTE[4], label="speaker positions",
                   zorder=2)
    for cam in picture.cameras:
        ax.plot(cam.centre_m[0], cam.centre_m[2], "s", ms=3, mec="k",
                mfc="k" if cam.calibrated else "white", zorder=3)
    ax.set_aspect("equal", adjustable="datalim")
    ax.xaxis.set_major_locator(MaxNLocator(5))  # the stretched axis's labels stay inside
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m, forward)")


def _scene_handles(picture: ArrayPicture) -> list[Artist]:
    """The scene view's markers, for the figure's legend (a legend inside the view would
    cover the array or the speakers, which fill it)."""
    handles: list[Artist] = [Line2D([], [], marker="o", ls="none", color=PALETTE[0], ms=3,
                                    label="microphone (scene view)")]
    if picture.sources_m is not None and len(picture.sources_m):
        handles.append(Line2D([], [], marker="o", ls="none", color=PALETTE[4], ms=3,
                              label="speaker position (scene view)"))
    return handles


def _freeze_limits(ax: Axes) -> None:
    """Keep the limits an equal-aspect "datalim" axes chose at the last draw and keep the
    aspect by its box from now on: the layout then sees the tick labels of those limits (it
    runs before "datalim" widens them, and a label at the new end would be cut off)."""
    x, y = ax.get_xlim(), ax.get_ylim()
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlim(x)
    ax.set_ylim(y)


@styled
def geometry_figure(picture: ArrayPicture) -> Figure:
    """The figure (module docstring); its axes are equal-aspect, gid "view-<name>"."""
    positions = np.asarray(picture.positions_m, dtype=np.float64)
    extent = _extent(positions)
    scale = _magnification(picture, extent)
    errors = scale.error_m
    fig = new_figure(PAGE_IN, 6.2)
    axes = fig.subplots(2, 2)
    for ax, (title, i, j) in zip(axes.ravel()[:3], VIEWS, strict=True):
        _draw_view(ax, picture, i, j, scale)
        ax.set_title(f"{title} ({AXIS_NAMES[i]}, {AXIS_NAMES[j]})")
        ax.set_gid(f"view-{title.split(',')[0]}")
    _draw_scene(axes[1, 1], picture)
    fig.canvas.draw()  # the layout, so that the camera labels can be measured
    for ax, (_, i, j) in zip(axes.ravel()[:3], VIEWS, strict=True):
        _label_cameras(ax, picture.cameras, i, j, 1e3 * 0.04 * extent)
    axes[1, 1].set_title("scene, top view")
    axes[1, 1].set_gid("view-scene")
    _freeze_limits(axes[1, 1])
    handles: list[Artist] = [Line2D([], [], marker="o", ls="none", mfc="none", mec="0.35", ms=4,
                      label=picture.reference_label if picture.reference_m is not None
                      else "calibrated position")]
    if errors is not None:
        handles.append(Line2D([], [], color=PALETTE[1], lw=1.5, label=(
            f"error {TIMES} {scale.errors:g} (calibrated {MINUS} {picture.reference_label})")))
    if picture.covariance_m2 is not None:
        handles.append(Ellipse((0, 0), 1, 1, facecolor=PALETTE[5], alpha=0.25,
                               label=f"95 % uncertainty {TIMES} {scale.ellipses:g}"
                               + ("" if scale.ellipses == scale.errors or errors is None
                                  else " (smaller: they would cover the array)")))
    handles.append(Line2D([], [], marker="s", ls="none", mfc="k", mec="k", ms=4,
                          label="camera and its optical axis"))
    if not all(c.calibrated for c in picture.cameras):
        handles.append(Line2D([], [], marker="s", ls="none", mfc="white", mec="k", ms=4,
                              label=f"camera not calibrated ({picture.reference_label})"))
    handles += _scene_handles(picture)
    fig.legend(handles=handles, loc="outside lower center", ncol=2)
    title = f"{len(positions)} microphones in the camera-0 frame"
    if errors is not None:
        norms = 1e3 * np.linalg.norm(errors, axis=1)
        title += (f"; against the {picture.reference_label}: mean {np.nanmean(norms):.3g} mm, "
                  f"max {np.nanmax(norms):.3g} mm")
        inside = inside_ellipsoids(errors, picture.covariance_m2)
        if inside is not None:
            title += (f"\n{inside[0]} of {inside[1]} errors inside their 95 % uncertainty "
                      "ellipsoid")
    if picture.missing:
        title += "\nnot drawn: " + "; ".join(picture.missing)
    fig.suptitle(title)
    return fig
