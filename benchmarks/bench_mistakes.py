"""The capture's mistakes (issue 33): for each mistake the simulated world can make, alone or
two at a time, whether the calibration names it, what else it names (false findings), and
the mean microphone error against the truth with the mistake beside the same session
without it.

Every session is `micam simulate --lab realistic` (48-microphone scatter array by default)
with `--mistake NAME` at the mistake's drawn defaults; the clean session of each seed is the
same world without mistakes. Found means a finding of the expected kind (`EXPECTED`) for
each of the session's mistakes; a false finding is any other kind. Every calibration is
given the array's nominal layout (`calibration.truth.nominal_layout_of`: the simulated
positions off by 0.5 mm per axis, in a frame of their own), against which swapped microphone
cables and a shifted column map are found; `--no-layout` leaves it out (and the one `micam
simulate` writes into the session's description).

    .venv/bin/python benchmarks/bench_mistakes.py [--poses 8] [--seeds 1] [--keep DIR]
    .venv/bin/python benchmarks/bench_mistakes.py --poses 20 --seeds 1 2 3 4 5 --pairs \
        --workers 2 --keep /tmp/mistakes

Each session (a seed and its mistakes) is a task: on a local Dask cluster with --workers N,
or on --scheduler ADDRESS (whose workers must see --keep at the same path).

Printed as a markdown table, written as JSON to benchmarks/results/mistakes.json (or --out).
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from calibration.checks.coverage import coverage
from calibration.errors import CalibrationInputError
from calibration.pipeline import CalibrationOptions, CalibrationRun, calibrate
from calibration.result import compare_with_truth
from calibration.truth import nominal_layout_of
from micam.cluster import add_cluster_options, cluster_map

EXPECTED = {
    "dead-mic": "dead-microphone",
    "inverted-mic": "inverted-microphone",
    "intermittent-mic": "intermittent-microphone",
    "clipped-bursts": "clipped-bursts",
    "silent-speaker": "silent-speaker",
    "swap-speakers": "swapped-speakers",
    "moved-pose": "moved-pose",
    "swap-mics": "swapped-microphones",  # against the nominal layout
    "board-shift": "shifted-boards",
    "hidden-board": "hidden-board",
    "motion-blur": "motion-blur",
    "glare": "glare",
    "mjpeg": "mjpeg",
    "distorted-speaker": "distorted-speaker",
    "refmic-far": "misplaced-reference-microphone",
    "close-reflector": "close-reflection",
}
"""Each mistake and the finding kind that names it."""


def _session(root: Path, name: str, seed: int, poses: int, array: str,
             mistakes: tuple[str, ...]) -> Path:
    """The session `name` under `root`, simulated unless it is there already."""
    path = root / f"{name}-s{seed}"
    if not (path / "truth.json").is_file():
        args = [sys.executable, "-m", "micam.cli", "simulate", "--out", str(path), "--quiet",
                "--lab", "realistic", "--array", array, "--poses", str(poses),
                "--mls-order", "12", "--seed", str(seed)]
        for mistake in mistakes:
            args += ["--mistake", mistake]
        subprocess.run(args, check=True)
    return path


def _calibrated(path: Path, layout: bool) -> dict:
    """Findings, error, its cover by the stated uncertainty and run time of one calibration
    (or its refusal), given the array's nominal layout or not."""
    truth = json.loads((path / "truth.json").read_text())
    start = time.perf_counter()
    try:
        run = calibrate(path, CalibrationOptions(
            layout=nominal_layout_of(truth) if layout else None, described_layout=layout))
    except CalibrationInputError as exc:
        return {"refused": str(exc), "findings": [], "error_mm": None,
                "seconds": round(time.perf_counter() - start, 2)}
    seconds = round(time.perf_counter() - start, 2)
    return {"refused": None, "findings": [f.kind for f in run.result.findings],
            "error_mm": round(1e3 * compare_with_truth(run.result, truth)["mean_mic_error_m"], 4),
            **_covered(run, truth), "seconds": seconds}


def _covered(run: CalibrationRun, truth: dict) -> dict:
    """How the result's stated uncertainty covers its errors (calibration.checks.coverage):
    the share of the located microphones inside their 95.4 % ellipsoid, and the chi-square
    of the array's common motion (7 degrees of freedom); empty without the joint fit."""
    if run.bundle is None:
        return {}
    true = {m["id"]: np.array(m["position_m"]) for m in truth["microphones"]}
    error = run.solution.positions_m - np.array([true[int(i)] for i in run.data.mic_ids])
    located = np.flatnonzero(np.isfinite(error).all(axis=1))
    mics = run.bundle.parameter_slices["microphones"]
    index = (3 * located[:, None] + np.arange(3)).ravel()
    split = coverage(error[located], run.bundle.covariance[mics, mics][np.ix_(index, index)],
                     run.solution.positions_m[located])
    return {"within_2_sigma": round(split.within_2_sigma, 3),
            "common_chi2": round(split.common_chi2, 1)}


def cell(root: Path, seed: int, combo: tuple[str, ...], poses: int, array: str,
         layout: bool) -> dict:
    """One session of `combo`'s mistakes (() for the clean one) simulated under `root` unless
    kept there, and calibrated: a task of its own, so that the grid runs on a cluster."""
    name = "+".join(combo) or "clean"
    got = _calibrated(_session(root, name, seed, poses, array, combo), layout)
    wanted = {EXPECTED[_kind(m)] for m in combo}
    return {"mistakes": list(combo), "seed": seed, **got,
            "found": wanted <= set(got["findings"]) if combo else None,
            "false_findings": sorted(set(got["findings"]) - wanted)}


def _kind(mistake: str) -> str:
    """The kind of a mistake as `micam simulate --mistake` takes it: NAME or NAME=ARGS."""
    return mistake.partition("=")[0]


def _mistake(text: str) -> str:
    """A --mistakes entry, checked: a kind of `EXPECTED`, with arguments or not."""
    if _kind(text) not in EXPECTED:
        raise argparse.ArgumentTypeError(
            f"unknown mistake {_kind(text)!r}; one of: {', '.join(EXPECTED)}")
    return text


def combinations(mistakes: list[str], pairs: str | None) -> list[tuple[str, ...]]:
    """Each mistake alone, then the pairs: each with the next of the list ("next", so that
    every mistake is in two pairs) or every pair ("all")."""
    combos = [(m,) for m in mistakes]
    if pairs == "next" and len(mistakes) > 1:
        following = mistakes[1:] + mistakes[:1]
        combos += list(dict.fromkeys(tuple(sorted((a, b), key=mistakes.index))
                                     for a, b in zip(mistakes, following, strict=True)))
    elif pairs == "all":
        combos += list(itertools.combinations(mistakes, 2))
    return combos


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=8)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--array", default="scatter48")
    parser.add_argument("--mistakes", nargs="+", default=list(EXPECTED), type=_mistake,
                        metavar="MISTAKE[=ARGS]",
                        help="as `micam simulate --mistake` takes them, e.g. mjpeg=70")
    parser.add_argument("--pairs", nargs="?", const="next", choices=["next", "all"],
                        help="also two mistakes at a time: each with the next one of the list "
                             "(--pairs) or every pair (--pairs all)")
    parser.add_argument("--no-layout", action="store_true",
                        help="calibrate without the array's nominal layout")
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep the sessions here (and reuse them)")
    add_cluster_options(parser, "the sessions", "--keep")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/mistakes.json"))
    args = parser.parse_args()
    combos = [(), *combinations(args.mistakes, args.pairs)]
    with tempfile.TemporaryDirectory() as scratch, \
            cluster_map("mistakes", args.scheduler, args.workers) as mapper:
        root = (args.keep or Path(scratch)).absolute()
        root.mkdir(parents=True, exist_ok=True)
        jobs = [(root, seed, combo, args.poses, args.array, not args.no_layout)
                for seed in args.seeds for combo in combos]
        rows = list(mapper(cell, jobs) if mapper else (cell(*job) for job in jobs))
    clean = {row["seed"]: row["error_mm"] for row in rows if not row["mistakes"]}
    for row in rows:
        row["clean_error_mm"] = clean[row["seed"]]
        row["ratio"] = (None if row["error_mm"] is None or not clean[row["seed"]]
                        else round(row["error_mm"] / clean[row["seed"]], 2))
    print(table(rows))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"poses": args.poses, "array": args.array,
                                    "layout": not args.no_layout, "rows": rows}, indent=1))
    print(f"written: {args.out}")


def table(rows: list[dict]) -> str:
    """The rows as a markdown table: mistake, seed, found, false findings, error with and
    without the mistake, their ratio, the share of microphones inside their stated 2-sigma
    ellipsoids with the common motion's chi-square, and the calibration's run time."""
    lines = ["| mistakes | seed | found | false findings | error mm | clean mm | ratio "
             "| within 2 sigma | common chi2 (7 dof) | s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        said = {None: "-", True: "yes", False: "NO"}[row["found"]]
        error = "refused" if row["refused"] else f"{row['error_mm']:.3f}"
        clean = "-" if row["clean_error_mm"] is None else f"{row['clean_error_mm']:.3f}"
        lines.append(f"| {' + '.join(row['mistakes']) or '(none)'} | {row['seed']} | {said} | "
                     f"{', '.join(row['false_findings']) or '-'} | {error} | {clean} | "
                     f"{row['ratio']} | {row.get('within_2_sigma', '-')} | "
                     f"{row.get('common_chi2', '-')} | {row['seconds']:.1f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
