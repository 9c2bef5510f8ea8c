"""The capture's mistakes (issue 33): for each mistake the simulated world can make, alone or
two at a time, whether the calibration names it, what else it names (false findings), and
the mean microphone error against the truth with the mistake beside the same session
without it.

Every session is `micam simulate --lab realistic` (48-microphone scatter array by default)
with `--mistake NAME` at the mistake's drawn defaults; the clean session of each seed is the
same world without mistakes. Found means a finding of the expected kind (`EXPECTED`); a
mistake without one (the calibration does not look for it yet) says "not looked for". Every
calibration is given the array's nominal layout (`calibration.truth.nominal_layout_of`: the
simulated positions off by 0.5 mm per axis, in a frame of their own), against which swapped
microphone cables and a shifted column map are found; `--no-layout` leaves it out (and the
one `micam simulate` writes into the session's description).

    .venv/bin/python benchmarks/bench_mistakes.py [--poses 8] [--seeds 1] [--keep DIR]
    .venv/bin/python benchmarks/bench_mistakes.py --poses 20 --seeds 1 2 3 4 5 --pairs

Printed as a markdown table, written as JSON to benchmarks/results/mistakes.json (or --out).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from calibration.errors import CalibrationInputError
from calibration.pipeline import CalibrationOptions, calibrate
from calibration.result import compare_with_truth
from calibration.truth import nominal_layout_of

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
"""Each mistake and the finding kind that names it (None: not looked for yet)."""


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
    """Findings, error and run time of one calibration (or its refusal), given the array's
    nominal layout or not."""
    truth = json.loads((path / "truth.json").read_text())
    start = time.perf_counter()
    try:
        run = calibrate(path, CalibrationOptions(
            layout=nominal_layout_of(truth) if layout else None, described_layout=layout))
    except CalibrationInputError as exc:
        return {"refused": str(exc), "findings": [], "error_mm": None,
                "seconds": round(time.perf_counter() - start, 2)}
    return {"refused": None, "findings": [f.kind for f in run.result.findings],
            "error_mm": round(1e3 * compare_with_truth(run.result, truth)["mean_mic_error_m"], 4),
            "seconds": round(time.perf_counter() - start, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses", type=int, default=8)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--array", default="scatter48")
    parser.add_argument("--mistakes", nargs="+", default=list(EXPECTED))
    parser.add_argument("--pairs", action="store_true",
                        help="also each mistake with the next one of the list")
    parser.add_argument("--no-layout", action="store_true",
                        help="calibrate without the array's nominal layout")
    parser.add_argument("--keep", type=Path, default=None, help="keep the sessions here")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/mistakes.json"))
    args = parser.parse_args()
    combos = [(m,) for m in args.mistakes]
    if args.pairs:
        combos += [(a, b) for a, b in zip(args.mistakes, args.mistakes[1:] + args.mistakes[:1],
                                         strict=True)]
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        root = args.keep or Path(scratch)
        root.mkdir(parents=True, exist_ok=True)
        print("| mistakes | seed | found | false findings | error mm | clean mm | ratio | s |")
        print("|---|---|---|---|---|---|---|---|")
        for seed in args.seeds:
            clean = _calibrated(_session(root, "clean", seed, args.poses, args.array, ()),
                                not args.no_layout)
            rows.append({"mistakes": [], "seed": seed, **clean,
                         "false_findings": clean["findings"]})
            print(f"| (none) | {seed} | - | {', '.join(clean['findings']) or '-'} | "
                  f"{clean['error_mm']:.3f} | {clean['error_mm']:.3f} | 1.0 | "
                  f"{clean['seconds']:.1f} |")
            for combo in combos:
                got = _calibrated(_session(root, "+".join(combo), seed, args.poses, args.array,
                                           combo), not args.no_layout)
                wanted = {EXPECTED[m] for m in combo} - {None}
                found = wanted <= set(got["findings"]) if wanted else None
                false = sorted(set(got["findings"]) - wanted)
                ratio = (None if got["error_mm"] is None or not clean["error_mm"]
                         else round(got["error_mm"] / clean["error_mm"], 2))
                rows.append({"mistakes": list(combo), "seed": seed, **got, "found": found,
                             "false_findings": false, "clean_error_mm": clean["error_mm"],
                             "ratio": ratio})
                said = "not looked for" if found is None else ("yes" if found else "NO")
                error = "refused" if got["refused"] else f"{got['error_mm']:.3f}"
                print(f"| {' + '.join(combo)} | {seed} | {said} | {', '.join(false) or '-'} | "
                      f"{error} | {clean['error_mm']:.3f} | {ratio} | {got['seconds']:.1f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"poses": args.poses, "array": args.array,
                                    "layout": not args.no_layout, "rows": rows}, indent=1))
    print(f"written: {args.out}")


if __name__ == "__main__":
    main()
