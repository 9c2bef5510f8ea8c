"""Residual figures of a calibration: times of flight, corner reprojections, TOF quality.

Time-of-flight residuals (measured minus modelled, outliers left out) per microphone (coloured
by board), per pose, per board, against the source-microphone distance and against the angle
of incidence, and their histogram beside a normal distribution of the same RMS: a model error
shows as structure in one of these (a trend with distance: c or a scale; with angle: sound
bending round the array body; one board: its latency; one pose: its board pose). The angle of
incidence is measured from the microphone's outward direction: the direction from the array's
centroid for a volumetric array, the plane's normal towards the sources for a flat one.

Corner reprojection residuals (detected minus modelled pixels) per camera, as a scatter with
equal axes and against the distance from the principal point (a distortion model that does
not fit shows as a trend there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from .style import MINUS, PAGE_IN, PALETTE, TIMES, category_colours, new_figure, styled

FLAT_RATIO = 0.1
"""An array whose smallest principal extent is below this fraction of its largest is flat."""


@dataclass(frozen=True)
class TofResiduals:
    """Time-of-flight residuals of a calibration.

    Attributes:
        residuals_s: (S, M) measured minus modelled, seconds; NaN where missing or an outlier.
        pose_of_source: (S,) the pose number of each source.
        sources_m: (S, 3) source positions, camera-0 frame.
        mics_m: (M, 3) microphone positions.
        mic_ids: (M,) microphone ids.
        boards: (M,) the board (serial) each microphone records on.
    """

    residuals_s: np.ndarray
    pose_of_source: np.ndarray
    sources_m: np.ndarray
    mics_m: np.ndarray
    mic_ids: np.ndarray
    boards: tuple[str, ...]


def _rms(values: np.ndarray, axis: int | None = None) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.nanmean(values**2, axis=axis))


def outward_directions(mics_m: np.ndarray, sources_m: np.ndarray) -> np.ndarray:
    """(M, 3) unit outward directions of the microphones (module docstring)."""
    centre = mics_m.mean(axis=0)
    d = mics_m - centre
    _, singular, vt = np.linalg.svd(d, full_matrices=False)
    if singular[-1] < FLAT_RATIO * singular[0]:
        normal = vt[-1] * np.sign((sources_m.mean(axis=0) - centre) @ vt[-1] or 1.0)
        return np.broadcast_to(normal, mics_m.shape).copy()
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def incidence_angles_deg(mics_m: np.ndarray, sources_m: np.ndarray) -> np.ndarray:
    """(S, M) angle between each microphone's outward direction and the direction from it to
    each source, degrees (0: facing the source)."""
    out = outward_directions(mics_m, sources_m)
    to_source = sources_m[:, None, :] - mics_m[None, :, :]
    to_source /= np.linalg.norm(to_source, axis=2, keepdims=True)
    cosine = np.clip(np.einsum("smk,mk->sm", to_source, out), -1.0, 1.0)
    return np.degrees(np.arccos(cosine))


def _binned(ax: Axes, x: np.ndarray, y: np.ndarray, bins: int = 12,
            signed: bool = True) -> None:
    """Scatter of y against x with the RMS of y in `bins` equal-width bins of x (drawn at
    +-RMS about 0 for signed y, at RMS for magnitudes), gid "rms-per-bin"."""
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    ax.scatter(x, y, s=1, color=PALETTE[0], alpha=0.15, linewidths=0, rasterized=True)
    if x.size == 0:
        return
    edges = np.linspace(x.min(), x.max(), bins + 1)
    which = np.clip(np.digitize(x, edges) - 1, 0, bins - 1)
    centres, rms = [], []
    for b in range(bins):
        inside = which == b
        if inside.sum() >= 5:
            centres.append(0.5 * (edges[b] + edges[b + 1]))
            rms.append(float(np.sqrt(np.mean(y[inside] ** 2))))
    ax.plot(centres, rms, "-o", color=PALETTE[1], ms=2.5, gid="rms-per-bin")
    if signed:
        ax.plot(centres, -np.array(rms), "-o", color=PALETTE[1], ms=2.5)
        ax.axhline(0.0, color="0.5", lw=0.5)
    else:
        ax.set_ylim(bottom=0.0)


def _rms_per_bin_handle(signed: bool) -> Line2D:
    """The legend entry of `_binned`'s line (one in the figure's legend, none over the
    points)."""
    return Line2D([], [], marker="o", color=PALETTE[1], ms=2.5,
                  label="± RMS per bin" if signed else "RMS per bin")


BOARD_LEGEND_COLUMNS = 5
"""Boards per row of the legend in the per-microphone panel."""


def _board_legend(fig: Figure, ax: Axes, colour: dict[str, str], tallest: float) -> None:
    """The boards' colours as a legend across the top of the bar panel `ax`, with the y axis
    raised so that no bar reaches the legend (measured on the laid-out figure)."""
    columns = min(len(colour), BOARD_LEGEND_COLUMNS)
    patches = [Patch(color=c, label=b) for b, c in colour.items()]
    # matplotlib fills a legend column by column: this order reads along its rows
    legend = ax.legend(handles=[h for c in range(columns) for h in patches[c::columns]],
                       loc="upper center", ncol=columns,
                       handlelength=1.0, handletextpad=0.4, columnspacing=0.8,
                       borderaxespad=0.2)
    legend.set_gid("board-legend")
    fig.draw_without_rendering()  # the layout: the legend's height in the axes
    share = legend.get_window_extent().height / ax.get_window_extent().height
    ax.set_ylim(0.0, tallest / max(1.0 - share - 0.06, 0.3))


@styled
def tof_residual_figure(data: TofResiduals) -> Figure:
    """The time-of-flight residual figure (module docstring); residuals in nanoseconds. The
    bar panel's boards are named in a legend of their colours (gid "board-legend"), the RMS
    lines and the normal distribution in the figure's legend, below the panels."""
    ns = 1e9 * np.asarray(data.residuals_s, dtype=np.float64)
    fig = new_figure(PAGE_IN, 7.4)
    axes = fig.subplots(3, 2)
    boards = sorted(set(data.boards))
    colour = dict(zip(boards, category_colours(len(boards)), strict=True))
    ax = axes[0, 0]
    per_mic = _rms(ns, axis=0)
    ax.bar(np.asarray(data.mic_ids), per_mic, width=0.8,
           color=[colour[b] for b in data.boards])
    ax.set(title="RMS per microphone (colour: board)", xlabel="microphone id",
           ylabel="residual RMS (ns)")
    ax = axes[0, 1]
    poses = np.unique(data.pose_of_source)
    per_pose = [_rms(ns[data.pose_of_source == p]) for p in poses]
    ax.bar(poses, per_pose, width=0.8, color=PALETTE[2])
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # poses are numbered, never 2.5
    ax.set(title="RMS per pose", xlabel="pose", ylabel="residual RMS (ns)")
    ax = axes[1, 0]
    samples = [ns[:, [b == board for b in data.boards]].ravel() for board in boards]
    samples = [s[np.isfinite(s)] for s in samples]
    ax.boxplot(samples, showfliers=False, widths=0.6)
    ax.set_xticks(range(1, len(boards) + 1), boards, rotation=30, ha="right")
    ax.set(title="per board (box: quartiles, whiskers: 1.5 IQR)", ylabel="residual (ns)")
    ax = axes[1, 1]
    distance = np.linalg.norm(data.sources_m[:, None, :] - data.mics_m[None], axis=2)
    _binned(ax, distance.ravel(), ns.ravel())
    ax.set(title="against source-microphone distance", xlabel="distance (m)",
           ylabel="residual (ns)")
    ax = axes[2, 0]
    _binned(ax, incidence_angles_deg(data.mics_m, data.sources_m).ravel(), ns.ravel())
    ax.set(title="against the angle of incidence (0: facing the source)",
           xlabel="angle of incidence (deg)", ylabel="residual (ns)")
    ax = axes[2, 1]
    finite = ns[np.isfinite(ns)]
    rms = float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")
    normal = Line2D([], [], color=PALETTE[1], label="normal distribution of the same RMS")
    if finite.size:
        ax.hist(finite, bins=60, density=True, color=PALETTE[0], alpha=0.7)
        reach = float(np.max(np.abs(finite)))
        x = np.linspace(-reach, reach, 200)
        ax.plot(x, np.exp(-0.5 * (x / rms) ** 2) / (rms * np.sqrt(2 * np.pi)), color=PALETTE[1])
        ax.set_xlim(-1.05 * reach, 1.05 * reach)  # centred: a bias shows as an offset
    ax.set(title=f"all {finite.size} residuals, RMS {rms:.3g} ns", xlabel="residual (ns)",
           ylabel="density")
    fig.legend(handles=[_rms_per_bin_handle(signed=True), normal], loc="outside lower center",
               ncol=2)
    fig.suptitle(f"Time-of-flight residuals (measured {MINUS} modelled), outliers left out")
    if boards:
        _board_legend(fig, axes[0, 0], colour, float(np.nanmax(per_mic, initial=0.0)) or 1.0)
    return fig


@dataclass(frozen=True)
class CornerResiduals:
    """One camera's corner reprojection residuals.

    Attributes:
        camera: its name.
        residuals_px: (N, 2) detected minus modelled corner pixels.
        corners_px: (N, 2) the detected corners.
        principal_point_px: (2,) cx, cy.
        n_views: images the corners come from.
    """

    camera: str
    residuals_px: np.ndarray
    corners_px: np.ndarray
    principal_point_px: np.ndarray
    n_views: int


CAMERAS_PER_ROW = 3
"""Cameras side by side in the corner figure (more start another pair of rows): at a page's
width a column is then wide enough for its titles and labels."""


@styled
def corner_residual_figure(cameras: list[CornerResiduals]) -> Figure:
    """Corner reprojection residuals, one column per camera, `CAMERAS_PER_ROW` to a pair of
    rows (module docstring); the circle and the RMS line are explained in the figure's
    legend, below the panels, so that no legend covers the points and every title and label
    fits its column."""
    n = min(max(len(cameras), 1), CAMERAS_PER_ROW)
    pairs = max(1, -(-len(cameras) // CAMERAS_PER_ROW))
    fig = new_figure(PAGE_IN, 4.4 * pairs + 0.4)
    grid = fig.subplots(2 * pairs, n, squeeze=False)
    axes = np.concatenate([grid[2 * p:2 * p + 2] for p in range(pairs)], axis=1)
    limit = max((float(np.max(np.abs(c.residuals_px))) for c in cameras if c.residuals_px.size),
                default=1.0)
    for k, cam in enumerate(cameras):
        r = np.asarray(cam.residuals_px, dtype=np.float64)
        rms = float(np.sqrt(np.mean(np.sum(r**2, axis=1)) / 2)) if r.size else float("nan")
        ax = axes[0, k]
        ax.scatter(r[:, 0], r[:, 1], s=1, color=PALETTE[0], alpha=0.3, linewidths=0,
                   rasterized=True)
        circle = np.linspace(0, 2 * np.pi, 100)
        ax.plot(np.sqrt(2) * rms * np.cos(circle), np.sqrt(2) * rms * np.sin(circle),
                color=PALETTE[1], lw=0.8)
        ax.set_aspect("equal")
        ax.set_xlim(-limit, limit)
        ax.set_ylim(limit, -limit)  # image rows grow downwards
        ax.set(title=f"{cam.camera}: {cam.n_views} views, {len(r)} corners,\n"
                     f"RMS {rms:.3g} px per coordinate", xlabel="dx (px)", ylabel="dy (px)")
        ax = axes[1, k]
        radius = np.linalg.norm(cam.corners_px - cam.principal_point_px, axis=1)
        _binned(ax, radius, np.linalg.norm(r, axis=1), bins=10, signed=False)
        ax.set(title=f"{cam.camera}: against the radius\n(from the principal point)",
               xlabel="radius (px)", ylabel="|residual| (px)")
    for k in range(len(cameras), axes.shape[1]):
        axes[0, k].set_visible(False)
        axes[1, k].set_visible(False)
    fig.legend(handles=[Line2D([], [], color=PALETTE[1], lw=0.8,
                               label=f"circle of the RMS radius (\u221a2 {TIMES} RMS per "
                                     "coordinate)"),
                        _rms_per_bin_handle(signed=False)],
               loc="outside lower center", ncol=2)
    fig.suptitle(f"Checkerboard corner reprojection residuals (detected {MINUS} modelled)")
    return fig


@styled
def tof_quality_figure(snr_db: np.ndarray, peak_to_sidelobe_db: np.ndarray) -> Figure:
    """Histograms of the times of flight's in-band SNR and peak-to-sidelobe ratio."""
    fig = new_figure(PAGE_IN, 2.6)
    a, b = fig.subplots(1, 2)
    snr = np.asarray(snr_db, dtype=np.float64).ravel()
    a.hist(snr[np.isfinite(snr)], bins=40, color=PALETTE[0])
    a.set(title="in-band SNR of every measurement", xlabel="SNR (dB)", ylabel="measurements")
    psr = np.asarray(peak_to_sidelobe_db, dtype=np.float64).ravel()
    b.hist(psr[np.isfinite(psr)], bins=40, color=PALETTE[3])
    b.set(title="correlation peak over its highest sidelobe", xlabel="peak-to-sidelobe (dB)",
          ylabel="measurements")
    fig.suptitle("Time-of-flight quality")
    return fig
