"""The one look of micam's figures: sizes for a paper's columns and a screen, fonts, colours.

Sizes are those of a two-column journal page (IEEE: a column 3.5 in, the page 7.16 in wide);
at `DPI` a page-wide figure is about 1070 pixels across, readable on a screen without
scaling. Text is 8 pt (7 pt for tick labels), the size a journal prints figure text at.
Colours: `MAP_COLORMAP` for acoustic maps (perceptually uniform, monotonic in lightness, so
that a level reads the same in grey print), the Okabe-Ito palette (`PALETTE`, distinguishable
with the common colour-vision deficiencies) for lines and categories.
"""

from __future__ import annotations

import io
import logging
import multiprocessing
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from PIL import Image

matplotlib.use("Agg")  # headless: figures are drawn on servers without a display
import matplotlib.pyplot as plt
import matplotlib.style
from matplotlib.axis import Axis
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.rcsetup import cycler
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

from acquisition.contracts.session import write_atomic

_log = logging.getLogger(__name__)

COLUMN_IN = 3.5
"""Width of one column of a two-column page, inches."""
PAGE_IN = 7.16
"""Width of a two-column page, inches."""
DPI = 150
"""Pixels per inch of the PNGs."""
MAP_COLORMAP = "inferno"
"""Acoustic maps: perceptually uniform, dark = low level (never jet)."""
PALETTE = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000",
           "#999999")
"""Okabe-Ito colours (blue, vermillion, green, purple, orange, sky blue, black) and a grey;
their yellow is left out, too pale on white."""

WIDE_PALETTE = "tab20"
"""Categories beyond `PALETTE`'s eight (a rig's nine boards): matplotlib's 20 distinct colours,
so that no two share one."""


def category_colours(n: int) -> list[str]:
    """n distinct colours for n categories: `PALETTE` when it has enough, else
    `WIDE_PALETTE` (repeating only beyond its 20)."""
    if n <= len(PALETTE):
        return list(PALETTE[:n])
    wide = matplotlib.colormaps[WIDE_PALETTE]
    return [to_hex(wide(k % wide.N)) for k in range(n)]


TIMES = "\u00d7"
"""The multiplication sign, for magnifications in labels."""
MINUS = "\u2212"
"""The minus sign, for differences in labels."""

PNG_COLOURS = 256
"""Colours of the PNG palette (`save`)."""

RC: dict[str, Any] = {
    "font.size": 8.0,
    "axes.titlesize": 8.0,
    "axes.labelsize": 8.0,
    "xtick.labelsize": 7.0,
    "ytick.labelsize": 7.0,
    "legend.fontsize": 7.0,
    "figure.titlesize": 9.0,
    "axes.linewidth": 0.6,
    "lines.linewidth": 1.0,
    "lines.markersize": 4.0,
    "grid.linewidth": 0.4,
    "grid.alpha": 0.5,
    "axes.grid": False,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "legend.frameon": False,
    "savefig.dpi": DPI,
    "figure.dpi": DPI,
    "image.cmap": MAP_COLORMAP,
    "axes.prop_cycle": cycler(color=list(PALETTE)),
}


def new_figure(width_in: float = PAGE_IN, height_in: float = 3.0, **kwargs) -> Figure:
    """A figure in micam's style, with constrained layout (no overlapping labels)."""
    with matplotlib.style.context(RC):
        fig = plt.figure(figsize=(width_in, height_in), layout="constrained", **kwargs)
    return fig


def nice_factor(value: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above `value` (> 0)."""
    exponent = np.floor(np.log10(value))
    for mantissa in (5.0, 2.0, 1.0):
        if mantissa * 10**exponent <= value:
            return float(mantissa * 10**exponent)
    return float(10 ** (exponent - 1) * 5)


def plain_log_ticks(axis: Axis) -> None:
    """Label a log axis at 1, 2 and 5 times the powers of ten, as plain numbers ("0.5", "20"),
    and its other minor ticks without labels: matplotlib's default labels minor ticks as
    "3x10^0" when an axis spans less than a decade or two, and they overlap."""
    axis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axis.set_minor_locator(LogLocator(base=10.0, subs=tuple(range(2, 10))))
    axis.set_minor_formatter(NullFormatter())


def styled(function):
    """Decorator: run a drawing function under micam's rcParams (they apply while artists
    are created, so every figure function runs inside them)."""

    def wrapper(*args, **kwargs):
        with matplotlib.style.context(RC):
            return function(*args, **kwargs)

    wrapper.__name__ = function.__name__
    wrapper.__doc__ = function.__doc__
    wrapper.__wrapped__ = function  # type: ignore[attr-defined]
    return wrapper


def save(fig: Figure, path: Path) -> Path:
    """Write the figure as PNG at `DPI` and close it. The image is reduced to a palette of
    `PNG_COLOURS` colours chosen for it, dithered so that smooth colour maps do not band
    (2-4x smaller than matplotlib's RGBA file, no visible change), and written atomically (a
    temporary name renamed into place). Returns the path."""
    path = Path(path)
    buffer = io.BytesIO()
    with matplotlib.style.context(RC):
        fig.savefig(buffer, format="png", dpi=DPI)
    plt.close(fig)
    buffer.seek(0)
    with Image.open(buffer) as image:
        return save_palette_png(image, path)


FigureJob = tuple[Callable[[], Figure], Path]
"""A figure to draw (the callable makes it) and the PNG to save it as."""

CHILD_TIMEOUT_S = 300.0
"""How long `save_all` waits for its child process before drawing the child's figures
itself."""


def save_all(jobs: Sequence[FigureJob]) -> list[Path]:
    """Draw and save several figures (`save`), every second one in a forked child process.

    Why: matplotlib holds the interpreter lock while it lays out and draws, so threads do not
    overlap, and the four figures of a 140-pose report take 2.4 s in one process, 1.3 s split
    over two cores. A forked child inherits the figures' data without pickling. Where the
    platform cannot fork, or the child fails (it logs why) or is not done within
    `CHILD_TIMEOUT_S`, its figures are drawn here instead. Returns the paths, in job order."""
    mine, theirs = list(jobs[1::2]), list(jobs[0::2])
    child = _start_child(theirs) if len(jobs) > 1 else None
    if child is None:
        mine = list(jobs)
    for make, path in mine:
        save(make(), path)
    if child is not None:
        child.join(CHILD_TIMEOUT_S)
        if child.is_alive():
            child.kill()
            child.join()
        if child.exitcode != 0:
            _log.warning("the figure process ended with status %s: drawing %s here",
                         child.exitcode, ", ".join(p.name for _, p in theirs))
            for make, path in theirs:
                save(make(), path)
    return [Path(path) for _, path in jobs]


def _start_child(jobs: list[FigureJob]) -> multiprocessing.process.BaseProcess | None:
    """A started forked process that saves `jobs`, or None where fork is unavailable."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return None
    process = multiprocessing.get_context("fork").Process(
        target=_save_in_child, args=(jobs,), name="micam-figures", daemon=True)
    try:
        process.start()
    except OSError as exc:  # no memory or process slots left: draw them here
        _log.warning("cannot start a figure process (%s): drawing every figure here", exc)
        return None
    return process


def _save_in_child(jobs: list[FigureJob]) -> None:
    """The child's work: save `jobs`; on any failure log it and end with status 1 (the parent
    then draws them), without the traceback a failing process target would print."""
    try:
        for make, path in jobs:
            save(make(), path)
    except Exception as exc:  # reported to the parent by the status, which redraws them
        _log.warning("drawing a figure failed in the figure process: %s", exc)
        os._exit(1)


def save_palette_png(image: Image.Image, path: Path) -> Path:
    """Write `image` as a PNG of `PNG_COLOURS` colours chosen for it, dithered (see `save`),
    atomically. Returns the path."""
    path = Path(path)
    rgb = image.convert("RGB")
    colours = rgb.quantize(PNG_COLOURS, method=Image.Quantize.FASTOCTREE)
    palette = rgb.quantize(palette=colours, dither=Image.Dither.FLOYDSTEINBERG)
    write_atomic(path, lambda fh: palette.save(fh, format="PNG", optimize=True), replace=True)
    return path
