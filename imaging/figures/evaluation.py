"""Figures of imaging evaluations: localization errors by band and their distribution, for
evaluations side by side (in-sample and held-out; with and without a CSM correction).

Left: the mean CLEAN-SC localization error in each band (solid: from the speaker as the camera
places it; dashed: from the true speaker position, when the evaluation has the truth). Right:
the cumulative distribution of the errors over every (recording, band), on a log axis. The
second figure: localization and map level against a simulated microphone phase error, with and
without a CSM correction.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from calibration.figures.style import PAGE_IN, PALETTE, new_figure, styled

from ..evaluate import Evaluation


@styled
def localization_figure(evaluations: Mapping[str, Evaluation], title: str) -> Figure:
    """The figure (module docstring); one colour per evaluation, in the given order, and one
    legend below both panels."""
    fig = new_figure(PAGE_IN, 3.0)
    by_band, spread = fig.subplots(1, 2)
    handles = []
    lowest = np.inf
    for k, (name, ev) in enumerate(evaluations.items()):
        colour = PALETTE[k % len(PALETTE)]
        bands = ev.by_band()
        freqs = np.array(list(bands)) / 1e3
        errors = np.sort([1e3 * r.error_m for r in ev.rows])
        lowest = min(lowest, float(np.percentile(errors, 0.5)))
        label = f"{name}: mean {errors.mean():.3g} mm"
        line, = by_band.plot(freqs, [1e3 * s.mean_m for s in bands.values()], "-o", ms=3,
                             color=colour)
        spread.plot(errors, np.arange(1, errors.size + 1) / errors.size, color=colour)
        if all(r.error_truth_m is not None for r in ev.rows):
            truth = np.sort([1e3 * (r.error_truth_m or 0.0) for r in ev.rows])
            by_band.plot(freqs, [1e3 * (s.truth_mean_m or np.nan) for s in bands.values()],
                         "--", color=colour)
            spread.plot(truth, np.arange(1, truth.size + 1) / truth.size, "--", color=colour)
            label += f" (from the truth {truth.mean():.3g} mm)"
        line.set_label(label)
        handles.append(line)
    by_band.set(title="mean error per band", xlabel="band centre (kHz)",
                ylabel="mean error (mm)")
    by_band.set_ylim(bottom=0.0)
    spread.set_xscale("log")
    spread.set_xlim(left=lowest)
    spread.set(title="distribution over recordings and bands", xlabel="error (mm)",
               ylabel="fraction below")
    handles += [Line2D([], [], color="0.3", label="from the speaker as the camera places it"),
                Line2D([], [], color="0.3", ls="--", label="from the true speaker position")]
    fig.legend(handles=handles, loc="outside lower center", ncol=2)
    fig.suptitle(title)
    return fig


@styled
def csm_calibration_figure(rows: list[dict], highlight_deg: float | None = 2.0) -> Figure:
    """Localization and map level against the simulated microphone phase error, without and
    with a CSM correction (`benchmarks/bench_csm_calibration.py`'s rows: "phase_error_deg",
    "correction" ("none", "eigen", ...), "mean_mm", "truth_mean_mm", "peak_db")."""
    fig = new_figure(PAGE_IN, 2.8)
    error_ax, peak_ax = fig.subplots(1, 2)
    names = {"none": "no correction", "eigen": "eigenvalue calibration (Dougherty)",
             "responses": "the exact responses"}
    for k, correction in enumerate(dict.fromkeys(r["correction"] for r in rows)):
        part = sorted((r for r in rows if r["correction"] == correction),
                      key=lambda r: r["phase_error_deg"])
        x = [r["phase_error_deg"] for r in part]
        style = {"color": PALETTE[k % len(PALETTE)], "ms": 3,
                 "label": names.get(correction, correction)}
        error_ax.plot(x, [r["mean_mm"] for r in part], "-o", **style)
        peak_ax.plot(x, [r["peak_db"] for r in part], "-o", **style)
    for ax in (error_ax, peak_ax):
        if highlight_deg is not None:
            ax.axvline(highlight_deg, color="0.6", lw=0.6, ls=":")
        ax.set_xlabel("microphone phase error, standard deviation (deg)")
        ax.grid(True)
    error_ax.set_yscale("log")
    error_ax.set(title="CLEAN-SC localization (5-15 kHz)", ylabel="mean error (mm)")
    peak_ax.axhline(0.0, color="0.5", lw=0.5)
    peak_ax.set(title="delay-and-sum peak level", ylabel="dB re the error-free array")
    error_ax.legend()
    fig.suptitle("The CSM calibration of paper VI against microphone phase errors")
    return fig
