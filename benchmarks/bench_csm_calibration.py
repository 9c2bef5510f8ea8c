"""What microphone phase errors do to the maps, and how much the CSM calibration of paper VI
(Dougherty's eigenvalue method) restores (issue 17).

A sphere72 session (default 10 poses at 0.6-1.0 m, default noise) is simulated and calibrated
by `micam calibrate`'s pipeline. Every recording is then imaged (CLEAN-SC on the rig plane,
1/12-octave bands 5-15 kHz, 6 mm grid) with a simulated per-microphone phase error of each
standard deviation asked for (constant over frequency, the same draw scaled), without
correction and with the eigenvalue calibration from one recording (default pose 0, speaker 4,
left out of every statistic), and at --exact-deg also with the exact responses (the best any
correction can do). Printed, and written as JSON to benchmarks/results/csm_calibration.json:
the mean CLEAN-SC localization error (from the speaker as the camera places it, and from the
truth) and the mean delay-and-sum peak level of the same (recording, band) pairs in dB re the
error-free, uncorrected maps.

With --capsules, a second session of the same seed is simulated with the world's own capsule
responses (`micam simulate --effect mic-responses`: delays and resonances, about 0.5 us of
group-delay spread, 2 degrees at 10 kHz) and calibrated with its responses; it is imaged with
the microphones' own delays left out of the steering (as before the joint fit estimated
them), with them in it (the default), corrected by the eigenvalue calibration, and corrected
by the calibration's microphone_responses (which hold the own delays, so the steering then
leaves them out).

    .venv/bin/python benchmarks/bench_csm_calibration.py [--poses 10] [--errors 0 1 2 5 10]
        [--calibration 0:4] [--capsules] [--keep DIR] [--figure docs/figures/csm_calibration.png]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from acquisition.contracts.session import SessionReader
from calibration.figures.style import save
from calibration.pipeline import calibrate
from imaging import load_geometry
from imaging.csm_calibration import ChannelResponses, simulated_phase_error
from imaging.evaluate import ImagingSettings, channel_calibration, evaluate_session
from imaging.figures.evaluation import csm_calibration_figure
from imaging.holdout import geometry_of
from micam.simulated import record_simulated_session
from sim.capture import SimulationOptions


def mm(metres: float | None) -> float:
    """Metres as millimetres to 4 decimals (NaN when there is no value)."""
    return float("nan") if metres is None else round(1e3 * metres, 4)


def scaled_error(n_mics: int, std_deg: float, seed: int) -> ChannelResponses:
    """The seed's unit phase error scaled to std_deg (so that the levels differ in size only)."""
    unit = np.angle(simulated_phase_error(n_mics, 1.0, seed).responses)
    return ChannelResponses(np.array([1.0]), np.exp(1j * std_deg * unit),
                            f"simulated phase error {std_deg:g} deg (seed {seed})")


def capsule_rows(session: Path, args: argparse.Namespace, skip: set) -> list[dict]:
    """The four imagings of a session with the world's capsule responses (module doc)."""
    if not (session / "truth.json").is_file():
        record_simulated_session(session, SimulationOptions(
            poses=args.poses, seed=args.seed, effects=("mic-responses",)))
    geometry = geometry_of(calibrate(session))
    truth = load_geometry(session / "truth.json")
    reader = SessionReader(session)
    base = ImagingSettings()
    pose, speaker = next(iter(skip))
    variants = {
        "own delays left out": (geometry.without_own_delays(), base),
        "own delays in the steering": (geometry, base),
        "eigen": (geometry, replace(base, correction=channel_calibration(
            reader, geometry, pose, speaker, base))),
        "responses": (geometry.without_own_delays(), replace(base,
                                                             correction=geometry.responses)),
    }
    rows = []
    for name, (geo, settings) in variants.items():
        s = evaluate_session(reader, geo, settings, workers=args.workers, skip=skip,
                             truth=truth).overall()
        rows.append({"imaging": name, "count": s.count, "mean_mm": round(1e3 * s.mean_m, 4),
                     "p95_mm": round(1e3 * s.p95_m, 4),
                     "truth_mean_mm": mm(s.truth_mean_m)})
        print(f"capsules  {name:>26}  mean {rows[-1]['mean_mm']:.3f} mm  p95 "
              f"{rows[-1]['p95_mm']:.3f} mm  from the truth {rows[-1]['truth_mean_mm']:.3f} mm",
              flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, default=10)
    parser.add_argument("--errors", type=float, nargs="+", default=[0.0, 1.0, 2.0, 5.0, 10.0],
                        metavar="DEG")
    parser.add_argument("--exact-deg", type=float, default=2.0)
    parser.add_argument("--calibration", default="0:4", metavar="POSE:SPEAKER")
    parser.add_argument("--seed", type=int, default=17)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--keep", type=Path, default=None, help="keep the session here")
    parser.add_argument("--figure", type=Path, default=None, help="also draw the figure")
    parser.add_argument("--capsules", action="store_true",
                        help="also measure on the world's own capsule responses")
    args = parser.parse_args()
    cal_pose, cal_speaker = (int(x) for x in args.calibration.split(":"))
    with tempfile.TemporaryDirectory() as tmp:
        session = (args.keep or Path(tmp)) / f"sphere72-{args.poses}"
        if not (session / "truth.json").is_file():
            record_simulated_session(session, SimulationOptions(poses=args.poses,
                                                                seed=args.seed))
        geometry = geometry_of(calibrate(session))
        truth = load_geometry(session / "truth.json")
        reader = SessionReader(session)
        skip = {(cal_pose, cal_speaker)}

        def evaluate(settings: ImagingSettings):
            return evaluate_session(reader, geometry, settings, workers=args.workers,
                                    skip=skip, truth=truth)

        base = ImagingSettings()
        t0 = time.perf_counter()
        reference = evaluate(base)
        peaks0 = {(r.pose, r.speaker, r.band_hz): r.dirty_peak for r in reference.rows}
        rows = []

        def record(deg: float, correction: str, ev) -> None:
            s = ev.overall()
            level = [10 * np.log10(r.dirty_peak / peaks0[(r.pose, r.speaker, r.band_hz)])
                     for r in ev.rows if (r.pose, r.speaker, r.band_hz) in peaks0]
            rows.append({"phase_error_deg": deg, "correction": correction, "count": s.count,
                         "mean_mm": round(1e3 * s.mean_m, 4),
                         "p95_mm": round(1e3 * s.p95_m, 4),
                         "truth_mean_mm": mm(s.truth_mean_m),
                         "peak_db": round(float(np.mean(level)), 4)})
            r = rows[-1]
            print(f"{deg:5.1f} deg  {correction:>9}  mean {r['mean_mm']:.3f} mm  p95 "
                  f"{r['p95_mm']:.3f} mm  from the truth {r['truth_mean_mm']:.3f} mm  peak "
                  f"{r['peak_db']:+.4f} dB  (n {r['count']})", flush=True)

        for deg in args.errors:
            error = scaled_error(geometry.n_mics, deg, args.seed) if deg else None
            settings = replace(base, simulated_error=error)
            record(deg, "none", reference if deg == 0 else evaluate(settings))
            eigen = channel_calibration(reader, geometry, cal_pose, cal_speaker, settings)
            record(deg, "eigen", evaluate(replace(settings, correction=eigen)))
            if deg == args.exact_deg and error is not None:
                record(deg, "responses", evaluate(replace(settings, correction=error)))
        figures = {"session": {"poses": args.poses, "seed": args.seed,
                               "calibration_recording": args.calibration},
                   "imaging": reference.to_json()["settings"], "rows": rows}
        if args.capsules:
            figures["capsules"] = capsule_rows(session.parent / f"{session.name}-capsules",
                                               args, skip)
        figures["total_s"] = round(time.perf_counter() - t0, 1)
    out = Path(__file__).parent / "results" / "csm_calibration.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(figures, indent=1))
    print(f"written: {out}")
    if args.figure is not None:
        save(csm_calibration_figure(rows, args.exact_deg), args.figure)
        print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
