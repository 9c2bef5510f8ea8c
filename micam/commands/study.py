"""`micam study`: the paper's Table II on simulated sessions, with the Cramer-Rao bound.

For every distance band, one session is simulated and measured once; the microphones are then
solved from random subsets of N sources, and the mean error against the truth is tabulated
beside the bound, as a table (Markdown), JSON and the paper's Fig. 14 (study.png). A band is
a cell (`study_band`): with --workers or --scheduler the bands run as tasks on a Dask cluster
(micam.cluster), with the same numbers.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from acquisition.contracts.errors import UserError
from .bounded import MLS_ORDER, SEED, integer

from ..cluster import cluster_map
from ..outputs import check_output_dirs

if TYPE_CHECKING:
    from sim.capture import SimulationOptions

DEFAULT_BANDS = ("0.4-0.6", "0.6-1.0", "1.0-1.5", "1.5-2.0")
DEFAULT_SOURCES = (3, 6, 12, 18, 36, 48, 96, 180)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="mean microphone error against the number of sources",
                       description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="directory for sessions and results")
    p.add_argument("--bands", nargs="+", default=list(DEFAULT_BANDS), metavar="MIN-MAX",
                   help="distance bands in metres (default: the paper's four)")
    p.add_argument("--poses", type=integer(1, 10_000), default=30, help="poses simulated per band")
    p.add_argument("--sources", type=integer(1, 60_000), nargs="+", default=list(DEFAULT_SOURCES),
                   help="numbers of sources (up to 6, or multiples of 6)")
    p.add_argument("--trials", type=integer(1, 1000), default=5, help="random subsets per number")
    p.add_argument("--array", default="sphere72",
                   help="simulated array: sphere72 (default), planar64 or scatter48")
    p.add_argument("--mls-order", type=MLS_ORDER, default=14,
                   help="order of the MLS bursts, a period of 2**order - 1 samples (default 14)")
    p.add_argument("--seed", type=SEED, default=0,
                   help="seed of the simulated world and of the subsets drawn (default 0)")
    p.add_argument("--workers", type=integer(1, 256), default=None, metavar="N",
                   help="run the bands as tasks on a local Dask cluster of N processes "
                        "(default: one after another in this process); the same numbers")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the bands as tasks on this Dask scheduler, e.g. tcp://HOST:8786, "
                        "whose workers see --out at the same path (see docs/batch.md)")
    p.set_defaults(run=run)


def _band(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in text.split("-"))
    except ValueError:
        raise UserError(f"band {text!r} is not MIN-MAX in metres, e.g. 0.6-1.0") from None
    return lo, hi


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from calibration.figures.study import study_figure
    from calibration.figures.style import save
    from calibration.study import PAPER_TABLE_II_MM
    from pydantic import ValidationError

    from sim.capture import SimulationOptions

    bands = [_band(b) for b in args.bands]
    too_many = [n for n in args.sources if n > 6 * args.poses]
    if too_many:
        raise UserError(f"--sources {too_many} need more than the {args.poses} poses simulated")
    check_output_dirs(("--out", args.out))
    out = args.out.absolute()  # the workers of a cluster may run in another directory
    jobs = []
    for i, band in enumerate(bands):
        try:
            options = SimulationOptions(array=args.array, poses=args.poses, distance_m=band,
                                        seed=args.seed + i, mls_order=args.mls_order)
        except ValidationError as exc:
            raise UserError(f"band {band}: {exc}") from None
        jobs.append((out / f"band-{band[0]:.1f}-{band[1]:.1f}", options, args.sources,
                     args.trials, args.seed))
    out.mkdir(parents=True, exist_ok=True)
    with cluster_map("study-band", args.scheduler, args.workers) as mapper:
        cells = mapper(study_band, jobs) if mapper else (study_band(*job) for job in jobs)
        results = list(tqdm(cells, total=len(jobs), desc="bands", unit="band"))
    (out / "study.json").write_text(json.dumps(results, indent=1))
    table = _markdown(results, PAPER_TABLE_II_MM)
    (out / "study.md").write_text(table)
    save(study_figure(results), out / "study.png")
    print(table)
    print(f"written: {args.out / 'study.md'}, study.json, study.png")
    return 0


def study_band(session: Path, options: SimulationOptions, sources: list[int], trials: int,
               seed: int) -> dict:
    """One cell of the study: a band's session simulated (at `session`), and its
    `band_rows`."""
    from micam.simulated import record_simulated_session

    truth = record_simulated_session(session, options)
    return band_rows(session, truth, sources, trials, seed) | {"band_m": options.distance_m}


def band_rows(session: Path, truth: dict, sources: list[int], trials: int, seed: int
              ) -> dict:
    """A simulated session measured, and its rows for every number of sources, as
    study.json holds them (but for the band)."""
    from calibration.pipeline import measure
    from calibration.study import source_count_study, sources_needed

    rows = source_count_study(measure(session), truth, sources, trials, seed=seed)
    return {"rows": [r.to_json() for r in rows],
            "sources_needed": {str(k): v for k, v in sources_needed(rows).items()}}


def _markdown(results: list[dict], thresholds: tuple[float, ...]) -> str:
    from calibration.study import JOINT_FROM_SOURCES

    lines = ["| band (m) | sources | camera-frozen error (mm) | CRLB (mm) | error / CRLB | "
             "latency | joint fit error (mm) |", "|---|---|---|---|---|---|---|"]
    for res in results:
        lo, hi = res["band_m"]
        for r in res["rows"]:
            joint = ("—" if r["joint_error_m"] is None else
                     f"{1e3 * r['joint_error_m']:.3f} ± {1e3 * r['joint_sem_m']:.3f}")
            lines.append(f"| {lo:.1f}-{hi:.1f} | {r['n_sources']} | "
                         f"{1e3 * r['mean_error_m']:.3f} ± {1e3 * r['sem_m']:.3f} | "
                         f"{1e3 * r['crlb_m']:.3f} | {r['efficiency']:.2f} | {r['latency']} | "
                         f"{joint} |")
    lines += ["", "Sources needed for the paper's Table II thresholds by the camera-frozen "
              "solver (paper, 0.6-1.0 m: 3 / 6 / 18 / 35); the joint fit, run from "
              f"{JOINT_FROM_SOURCES} sources on, is below all of them there:", "",
              "| band (m) | " + " | ".join(f"< {t} mm" for t in thresholds) + " |",
              "|---|" + "---|" * len(thresholds)]
    for res in results:
        lo, hi = res["band_m"]
        needed = [res["sources_needed"][str(t)] for t in thresholds]
        lines.append(f"| {lo:.1f}-{hi:.1f} | " + " | ".join(
            str(n) if n is not None else "not reached" for n in needed) + " |")
    return "\n".join(lines) + "\n"
