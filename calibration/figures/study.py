"""The source-count study as the paper's Fig. 14: mean microphone error against the number of
sources, one panel per distance band, with the Cramer-Rao bound.

Each panel: the camera-frozen solver (circles, with the standard error over the random subsets
as bars), the joint optical-acoustic fit of the same subsets (squares), the bound of the
camera-frozen model for the same sources (dashed), and the paper's Table II for the distance
range of the paper that overlaps the band most (crosses: the sources the paper needed to get
below each of its error thresholds; its errors at those counts were at most that).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from ..study import PAPER_TABLE_II_MM, PAPER_TABLE_II_SOURCES
from .style import PAGE_IN, PALETTE, new_figure, plain_log_ticks, styled


def paper_range_for(band_m: tuple[float, float]) -> tuple[float, float] | None:
    """The paper's distance range overlapping `band_m` most (None if none overlaps)."""
    lo, hi = band_m
    overlaps = {r: min(hi, r[1]) - max(lo, r[0]) for r in PAPER_TABLE_II_SOURCES}
    best = max(overlaps, key=lambda r: overlaps[r])
    return best if overlaps[best] > 0 else None


@styled
def study_figure(results: list[dict]) -> Figure:
    """The figure from `micam study`'s results (study.json: per band "band_m" and "rows" of
    `StudyRow.to_json()`); panels share their log axes (ticks at 1, 2 and 5 times the powers
    of ten, labelled as plain numbers), gid "band-<k>"."""
    n = max(len(results), 1)
    fig = new_figure(PAGE_IN, 3.1)
    axes = np.atleast_1d(fig.subplots(1, n, sharex=True, sharey=True))
    for k, (ax, res) in enumerate(zip(axes, results, strict=False)):
        rows = res["rows"]
        sources = np.array([r["n_sources"] for r in rows])
        ax.errorbar(sources, [1e3 * r["mean_error_m"] for r in rows],
                    yerr=[1e3 * r["sem_m"] for r in rows], fmt="o-", ms=3, capsize=2,
                    color=PALETTE[0], label="camera frozen")
        ax.plot(sources, [1e3 * r["crlb_m"] for r in rows], "--", color=PALETTE[0],
                label="bound (frozen model)")
        joint = [(r["n_sources"], 1e3 * r["joint_error_m"], 1e3 * r["joint_sem_m"])
                 for r in rows if r["joint_error_m"] is not None]
        if joint:
            x, y, e = (np.array(v) for v in zip(*joint, strict=True))
            ax.errorbar(x, y, yerr=e, fmt="s:", ms=3, capsize=2, color=PALETTE[1],
                        label="joint fit")
        lo, hi = res["band_m"]
        title = f"{lo:.1f}-{hi:.1f} m"
        paper = paper_range_for((lo, hi))
        if paper is not None:
            points = [(s, t) for s, t in zip(PAPER_TABLE_II_SOURCES[paper], PAPER_TABLE_II_MM,
                                              strict=True) if s is not None]
            ax.plot(*zip(*points, strict=True), "x", color=PALETTE[6], ms=5,
                    label="paper's Table II: sources it needed to get below each error")
            title += f" (paper: {paper[0]:.1f}-{paper[1]:.1f} m)"
        ax.set_xscale("log")
        ax.set_yscale("log")
        plain_log_ticks(ax.xaxis)  # source counts and millimetres, as numbers
        plain_log_ticks(ax.yaxis)
        ax.grid(True, which="major")
        ax.set_title(title)
        ax.set_xlabel("sources")
        ax.set_gid(f"band-{k}")
    axes[0].set_ylabel("mean microphone error (mm)")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels))
    fig.suptitle("Mean microphone error against the number of sources (paper Fig. 14, "
                 "Table II)")
    return fig
