"""Acoustic maps on a camera's image (paper Fig. 15), side by side.

Each panel is the camera's image in grey with a map over it: a map resampled at the image's
pixels (`imaging.overlay.map_to_image`) is drawn in dB below the panel's peak, down to the
chosen dynamic range, in `MAP_COLORMAP` without its darkest tenth (black would read as a
shadow on the image) and fading out over the lowest third of the range; CLEAN-SC components
are drawn as markers where they lie, coloured on the same scale. Open circles are the
speakers where the camera places them (white; sky blue: the one that plays). One colour bar
gives the level's scale, a bar under each panel the length (`ScaleBar`, on the plane the map
lies in), and a legend below the panels says what the circles and markers are.
"""

from __future__ import annotations

from dataclasses import dataclass

import matplotlib
import numpy as np
from matplotlib.axes import Axes
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.offsetbox import AnchoredOffsetbox, AuxTransformBox, HPacker, TextArea

from ..errors import CalibrationInputError
from .style import MAP_COLORMAP, PAGE_IN, PALETTE, new_figure, nice_factor, styled

PLAYING_COLOUR = PALETTE[5]
"""The circle of the playing speaker (sky blue: absent from the map's colour map)."""
LAYER_ALPHA = 0.8
"""Opacity of the map layer above the lowest third of the range."""


def map_colours() -> ListedColormap:
    """`MAP_COLORMAP` from 10 % to 100 % of its range (its darkest tenth left out)."""
    base = matplotlib.colormaps[MAP_COLORMAP]
    return ListedColormap(base(np.linspace(0.1, 1.0, 256)), name=f"{MAP_COLORMAP}-light")


@dataclass(frozen=True)
class MapPanel:
    """One panel: a title, a map layer (height, width) of power per image pixel (NaN where
    there is none) and/or CLEAN-SC components at pixels (K, 2) with their powers (K,)."""

    title: str
    layer: np.ndarray | None = None
    components_px: np.ndarray | None = None
    components_power: np.ndarray | None = None


@dataclass(frozen=True)
class ScaleBar:
    """The image's scale where the map lies: `pixels_per_m` image pixels per metre there
    (perspective makes it vary over the image), and where that is ("at the playing speaker,
    on the rig plane")."""

    pixels_per_m: float
    where: str


SCALE_SHARE = 0.2
"""The scale bar's length: at most this fraction of the image's width, rounded down to 1, 2
or 5 times a power of ten millimetres."""


def _scale_bar(ax: Axes, scale: ScaleBar, width_px: int) -> None:
    """A bar of a round length in millimetres (`SCALE_SHARE`) with its length and where it
    holds written after it, below the panel's lower left corner, gid "scale-bar"."""
    length_m = nice_factor(SCALE_SHARE * width_px / scale.pixels_per_m)
    bar = AuxTransformBox(ax.transData)  # x in image pixels: the bar is length_m long there
    bar.add_artist(Line2D([0.0, length_m * scale.pixels_per_m], [0.0, 0.0], color="black",
                          lw=1.5, marker="|", ms=5, mew=1.0))
    label = TextArea(f"{1e3 * length_m:g} mm {scale.where}", textprops={"fontsize": 7})
    box = AnchoredOffsetbox("upper left", child=HPacker(children=[bar, label], sep=5,
                                                        align="center"),
                            bbox_to_anchor=(0.0, -0.02), bbox_transform=ax.transAxes,
                            borderpad=0.0, pad=0.0, frameon=False)
    box.set_gid("scale-bar")
    ax.add_artist(box)


def _ring(colour: str, label: str) -> Line2D:
    """A legend entry drawn as the speakers' open circles are."""
    return Line2D([], [], marker="o", ls="none", mfc="none", mec=colour, ms=7, mew=1.0,
                  label=label)


def _legend_handles(playing: int | None, components: bool) -> list[Line2D]:
    """What the circles and markers are, drawn as on the image."""
    handles = [_ring("white", "speaker, where the camera places it")]
    if playing is not None:
        handles.append(_ring(PLAYING_COLOUR, "the speaker that plays"))
    if components:
        handles.append(Line2D([], [], marker="o", ls="none", ms=5, mfc=map_colours()(1.0),
                              mec="black", mew=0.3,
                              label="CLEAN-SC component (colour and size: its level)"))
    return handles


def levels_db(power: np.ndarray, reference: float) -> np.ndarray:
    """10 log10(power / reference), NaN where power is not positive."""
    p = np.asarray(power, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(p > 0, 10.0 * np.log10(p / reference), np.nan)


@styled
def acoustic_map_figure(image: np.ndarray, panels: list[MapPanel], speakers_px: np.ndarray,
                        playing: int | None, dynamic_range_db: float, title: str,
                        scale: ScaleBar | None = None) -> Figure:
    """The figure (module docstring). Axes are in image pixels (x right, y down), one per
    panel with gid "map-<k>"; the colour bar's axes has gid "colour-bar", the legend (on the
    image's grey, so that its white circle shows) gid "map-legend"."""
    if dynamic_range_db <= 0:
        raise CalibrationInputError(f"dynamic range {dynamic_range_db} dB must be positive")
    grey = image if image.ndim == 2 else image[..., ::-1].mean(axis=2)
    height, width = grey.shape
    panel_w = PAGE_IN / len(panels) - 0.25
    fig = new_figure(PAGE_IN, panel_w * height / width + 1.0)
    axes = np.atleast_1d(fig.subplots(1, len(panels)))
    style = {"cmap": map_colours(), "vmin": -dynamic_range_db, "vmax": 0.0}
    mappable = None
    for k, (ax, panel) in enumerate(zip(axes, panels, strict=True)):
        ax.imshow(grey, cmap="gray", vmin=0, vmax=255, interpolation="antialiased")
        peak = max(np.nanmax(panel.layer) if panel.layer is not None else 0.0,
                   np.max(panel.components_power) if panel.components_power is not None
                   and len(panel.components_power) else 0.0)
        if panel.layer is not None and peak > 0:
            level = levels_db(panel.layer, peak)
            fade = np.clip(3.0 * (level + dynamic_range_db) / dynamic_range_db, 0.0, 1.0)
            mappable = ax.imshow(np.nan_to_num(level, nan=-dynamic_range_db),
                                 alpha=LAYER_ALPHA * np.nan_to_num(fade),
                                 interpolation="antialiased", **style)
        ax.scatter(speakers_px[:, 0], speakers_px[:, 1], s=60, facecolors="none",
                   edgecolors=["white" if i != playing else PLAYING_COLOUR
                               for i in range(len(speakers_px))],
                   linewidths=1.0, zorder=3)
        if panel.components_px is not None and panel.components_power is not None and peak > 0:
            level = levels_db(panel.components_power, peak)
            keep = level >= -dynamic_range_db
            order = np.argsort(level[keep])  # strongest drawn last, on top
            px = np.asarray(panel.components_px)[keep][order]
            lv = level[keep][order]
            mappable = ax.scatter(px[:, 0], px[:, 1], c=lv, s=8 + 30 * (1 + lv / dynamic_range_db),
                                  edgecolors="black", linewidths=0.3, zorder=4, **style)
        ax.set_xlim(-0.5, width - 0.5)
        ax.set_ylim(height - 0.5, -0.5)
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(panel.title)
        ax.set_gid(f"map-{k}")
        if scale is not None:
            _scale_bar(ax, scale, width)
    components = any(p.components_px is not None and len(p.components_px) for p in panels)
    legend = fig.legend(handles=_legend_handles(playing, components), loc="outside lower center",
                        ncol=3, frameon=True, facecolor="0.45", edgecolor="none",
                        framealpha=1.0, labelcolor="white")
    legend.set_gid("map-legend")
    if mappable is not None:
        bar = fig.colorbar(mappable, ax=list(axes), shrink=0.9, pad=0.01)
        bar.set_label("level re the panel's peak (dB)")
        bar.ax.set_gid("colour-bar")
    fig.suptitle(title)
    return fig
