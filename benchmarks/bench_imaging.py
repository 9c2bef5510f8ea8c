"""Acoustic imaging speed against Acoular, and CLEAN-SC localization on a simulated session.

Workload (issue 7): 72 microphones (the simulated 0.15 m sphere), 96 kS/s, 2 s of three
uncorrelated white-noise speakers about 1 m away (rendered by the simulated world), CSM with
4096-sample Hann blocks at 50 % overlap, a 101 x 101 grid at 6 mm on the speakers' plane,
'true location' steering, the 1/12-octave band at 8 kHz (20 bins).

Each stage runs through micam and through Acoular (an optional benchmark dependency:
`.venv/bin/pip install acoular`) in the same process, alternately, --repeat times (CLEAN-SC
--clean-pairs times), so that both see the same state of a shared machine; the figures are
the medians of the times and of the per-pair ratios, with the range of the ratios. Two
settings: on one thread (micam's `workers=1`, Acoular's numba on 1 thread; CPU time counts,
the steadier figure) and on all cores (micam's threads for beamforming and `workers=None`
processes for CLEAN-SC, Acoular's numba on all threads, its default; wall-clock time counts).
The CSM is one pass of BLAS products on one thread for micam in both settings. Neither
library's start-up is counted: micam's CLEAN-SC process pool is started and Acoular's numba
kernels compiled before the timing. The per-bin agreement of the maps is reported. micam's
beamforming runs in single precision (complex64 products on float64 phases,
`imaging.beamform`), its CLEAN-SC in float64 (see `imaging.cleansc`);
the beamforming maps are also computed in float64 and the difference reported.

Then the mean CLEAN-SC localization error over the 1/12-octave bands of 5-15 kHz is measured
on a simulated session with its truth geometry (paper VI-A: 6.6 mm at a 6 mm grid).

    .venv/bin/python benchmarks/bench_imaging.py [--poses 10] [--session DIR] [--repeat 5]
                                                 [--clean-pairs 2] [--skip-localization]

Prints the figures and writes them as JSON to benchmarks/results/imaging.json.

BLAS runs on one thread unless OPENBLAS_NUM_THREADS says otherwise: the setting Acoular itself
applies when it is imported first, and the faster one on a shared machine, where a BLAS thread
spinning for a descheduled partner loses more than the second core gains.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy is imported

import argparse
import functools
import json
import platform
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from acquisition.contracts.session import SessionReader
from imaging import (
    CleanScOptions,
    PlaneGrid,
    SteeringModel,
    WelchOptions,
    band_bins,
    beamform,
    clean_sc_spectra,
    cross_spectra,
    load_geometry,
)
from imaging.csm import acoular_block_count
from imaging.evaluate import ImagingSettings, evaluate_session
from sim.analog_bench import AcousticBench
from sim.arrays import array_layout
from sim.geometry import RigidTransform
from sim.multi_source import record_uncorrelated_noise
from sim.poses import FACING_CAMERA
from sim.world import World

BAND_HZ, FRACTION, N_GRID, SPACING_M = 8000.0, 12, 101, 0.006
STAGES = ("csm", "beamforming", "clean_sc")
DAS_PRECISION = "single"  # complex64 products on float64 phases (see imaging.beamform)


SETTINGS = ("one thread", "all cores")


def timed(run: Callable[[], object], setting: str) -> tuple[float, object]:
    """Seconds of one run: CPU time of this process on one thread (the steadier figure on a
    shared machine), wall-clock time on all cores."""
    clock = time.process_time if setting == "one thread" else time.perf_counter
    t0 = clock()
    result = run()
    return clock() - t0, result


def side_by_side(ours: Callable[[], object], theirs: Callable[[], object] | None,
                 setting: str, pairs: int) -> tuple[dict, object, object]:
    """Run micam and Acoular alternately `pairs` times, so that both see the same state of
    the machine, and take the median of the per-pair time ratios (and of each time)."""
    mine, other, ratios = [], [], []
    result = reference = None
    for _ in range(pairs):
        t, result = timed(ours, setting)
        mine.append(t)
        if theirs is not None:
            u, reference = timed(theirs, setting)
            other.append(u)
            ratios.append(u / t)
    figures = {"micam_s": float(np.median(mine)), "micam_runs_s": mine}
    if theirs is not None:
        figures.update({"acoular_s": float(np.median(other)), "acoular_runs_s": other,
                        "speedup": float(np.median(ratios)),
                        "speedup_range": [float(min(ratios)), float(max(ratios))]})
    return figures, result, reference


def workload(seed: int = 0):
    world = World(layout=array_layout("sphere72"), seed=seed)
    world.place_rig(RigidTransform(FACING_CAMERA, np.array([-0.075, 0.12, 1.0])))
    rec = record_uncorrelated_noise(AcousticBench(world), [0, 3, 4], 2.0, seed=seed,
                                    drive_rms_v=[1.0, 0.7, 0.5])
    centre = rec.speakers_m.mean(axis=0)
    half = SPACING_M * (N_GRID - 1) / 2
    grid = PlaneGrid.xy_plane((centre[0] - half, centre[0] + half),
                              (centre[1] - half, centre[1] + half), centre[2], SPACING_M)
    return world, rec, grid


def micam_stages(world, rec, grid, bins: np.ndarray) -> dict[str, Callable]:
    """Each stage through micam, given its workers (1: one thread, None: all cores)."""
    fs = rec.sample_rate_hz
    welch = WelchOptions(block_size=4096, overlap=0.5, window="hann")
    mics = world.layout.mic_positions_m
    c = world.speed_of_sound_m_s
    spectra = cross_spectra(rec.signals_v, fs, bins, welch)

    def das(workers, precision=DAS_PRECISION):
        steering = SteeringModel(grid.points, mics, c, "true location")
        return beamform(spectra, steering, precision=precision, workers=workers)

    def clean(workers):
        steering = SteeringModel(grid.points, mics, c, "true location")
        results = clean_sc_spectra(spectra, steering, CleanScOptions(), workers=workers)
        return np.array([r.clean_map for r in results]), [r.n_iterations for r in results]

    return {"csm": lambda workers: cross_spectra(rec.signals_v, fs, bins, welch),
            "beamforming": das, "clean_sc": clean}


def acoular_stages(world, rec, grid, bins: np.ndarray) -> dict[str, Callable] | None:
    """Each stage through Acoular, given its numba threads; None if it is not installed. The
    numba kernels are compiled (or loaded from cache) here, before any timing."""
    try:
        import acoular as ac
        import numba
    except ImportError:
        return None
    ac.config.global_caching = "none"
    fs = rec.sample_rate_hz
    mics = ac.MicGeom(pos_total=world.layout.mic_positions_m.T.copy())
    rect = ac.RectGrid(x_min=grid.u_m[0], x_max=grid.u_m[-1], y_min=grid.v_m[0],
                       y_max=grid.v_m[-1], z=float(grid.origin_m[2]), increment=SPACING_M)
    env = ac.Environment(c=world.speed_of_sound_m_s)

    def spectra(data):
        ts = ac.TimeSamples(data=data, sample_freq=fs)
        return ac.PowerSpectra(source=ts, block_size=4096, overlap="50%", window="Hanning",
                               precision="complex128")

    def band(kind, ps, **kw):
        steer = ac.SteeringVector(grid=rect, mics=mics, env=env, steer_type="true location")
        bf = kind(freq_data=ps, steer=steer, r_diag=True, **kw)
        bf.synthetic(BAND_HZ, FRACTION)
        return np.array([bf.result[int(k)] for k in bins])

    full = spectra(rec.signals_v)
    full.csm  # noqa: B018  (computed once here; the beamformer stages time only themselves)

    def with_threads(threads, run):
        numba.set_num_threads(threads or numba.config.NUMBA_NUM_THREADS)
        return run()

    for threads in (1, None):  # compile or load every kernel, on both thread settings
        with_threads(threads, lambda: band(ac.BeamformerCleansc,
                                           spectra(rec.signals_v[:16384]), n_iter=3))
    return {"csm": lambda t: with_threads(t, lambda: np.asarray(spectra(rec.signals_v).csm)),
            "beamforming": lambda t: with_threads(t, lambda: band(ac.BeamformerBase, full)),
            "clean_sc": lambda t: with_threads(t, lambda: band(ac.BeamformerCleansc, full)),
            "version": ac.__version__}


def per_bin_relative(a: np.ndarray, b: np.ndarray) -> float:
    """max over bins of max |a - b| / max |b| within the bin."""
    scale = np.abs(b).reshape(len(b), -1).max(axis=1)
    return float((np.abs(a - b).reshape(len(b), -1).max(axis=1) / scale).max())


def speed(repeat: int, clean_pairs: int) -> dict:
    world, rec, grid = workload()
    fs = rec.sample_rate_hz
    bins = band_bins(BAND_HZ, FRACTION, 4096, fs)
    mine = micam_stages(world, rec, grid, bins)
    theirs = acoular_stages(world, rec, grid, bins)
    mine["clean_sc"](None)  # starts micam's worker processes, before any timing
    report: dict = {"workload": {"mics": 72, "grid": [N_GRID, N_GRID], "spacing_m": SPACING_M,
                                 "duration_s": 2.0, "sample_rate_hz": fs, "band_hz": BAND_HZ,
                                 "fraction": FRACTION, "bins": int(bins.size),
                                 "steering": "true location"},
                    "micam_precision": {"beamforming": DAS_PRECISION, "clean_sc": "double"},
                    "acoular": theirs["version"] if theirs else "not installed "
                               "(pip install acoular to compare)"}
    outputs = {}
    for setting in SETTINGS:
        workers = 1 if setting == "one thread" else None
        report[setting] = {}
        for stage in STAGES:
            pairs = clean_pairs if stage == "clean_sc" else repeat
            other = (functools.partial(theirs[stage], workers) if theirs else None)
            report[setting][stage], out, ref = side_by_side(
                functools.partial(mine[stage], workers), other, setting, pairs)
            outputs[stage] = (out, ref)
    das_double = mine["beamforming"](None, "double")
    (das_maps, acoular_das) = outputs["beamforming"]
    ((clean_maps, iterations), acoular_clean) = outputs["clean_sc"]
    report["micam_clean_sc_iterations"] = iterations
    report["micam_beamforming_vs_float64_max_rel_per_bin"] = per_bin_relative(das_maps,
                                                                               das_double)
    if theirs:
        spectra = outputs["csm"][0]
        # Acoular normalises by a fractional block count (see imaging.csm).
        factor = spectra.n_blocks / acoular_block_count(rec.signals_v.shape[0], WelchOptions())
        report["csm_block_count_factor"] = factor
        report["agreement"] = {
            "csm_max_rel_per_bin": per_bin_relative(spectra.csm * factor,
                                                    outputs["csm"][1][bins]),
            "beamforming_max_rel_per_bin": per_bin_relative(das_maps * factor, acoular_das),
            "clean_sc_max_rel_per_bin": per_bin_relative(clean_maps * factor, acoular_clean),
            "clean_sc_band_rel": float(np.abs(clean_maps.sum(0) * factor
                                              - acoular_clean.sum(0)).max()
                                       / acoular_clean.sum(0).max()),
        }
    return report


def localization(session: Path | None, poses: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        if session is None:
            from micam.cli import main as micam

            session = Path(tmp) / "s"
            if micam(["simulate", "--out", str(session), "--poses", str(poses), "--quiet"]):
                raise RuntimeError("micam simulate failed")
        t0 = time.perf_counter()
        result = evaluate_session(SessionReader(session), load_geometry(session / "truth.json"),
                                  ImagingSettings())
        doc = result.to_json()
        doc["time_s"] = time.perf_counter() - t0
        doc["session"] = str(session)
        doc["paper_mean_mm"] = 6.6
        return doc


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5,
                        help="micam/Acoular pairs for the CSM and beamforming")
    parser.add_argument("--clean-pairs", type=int, default=2,
                        help="pairs for CLEAN-SC (Acoular takes 15-35 s per run)")
    parser.add_argument("--poses", type=int, default=10,
                        help="poses of the simulated session for the localization figure")
    parser.add_argument("--session", type=Path, help="evaluate this simulated session instead")
    parser.add_argument("--skip-localization", action="store_true")
    parser.add_argument("--out", type=Path,
                        default=Path(__file__).parent / "results" / "imaging.json")
    args = parser.parse_args()

    report = {"machine": {"python": platform.python_version(), "cpus": os.cpu_count(),
                          "openblas_threads": os.environ["OPENBLAS_NUM_THREADS"],
                          "load_average_before": os.getloadavg()}}
    report["speed"] = sp = speed(args.repeat, args.clean_pairs)
    report["machine"]["load_average_after_speed"] = os.getloadavg()
    for setting in SETTINGS:
        print(f"{setting} ({'CPU' if setting == 'one thread' else 'wall-clock'} time, medians"
              " of alternating runs):")
        for stage in STAGES:
            f = sp[setting][stage]
            line = f"  {stage:12s} micam {f['micam_s']:7.3f} s"
            if "speedup" in f:
                low, high = f["speedup_range"]
                line += (f" | acoular {f['acoular_s']:7.3f} s | micam {f['speedup']:5.1f}x "
                         f"faster (pairs: {low:.1f}-{high:.1f}x)")
            print(line)
    if "agreement" in sp:
        print("agreement with acoular:", json.dumps(sp["agreement"]))
    print(f"beamforming ({sp['micam_precision']['beamforming']} precision) against micam's "
          f"float64 maps: {sp['micam_beamforming_vs_float64_max_rel_per_bin']:.2e} max relative "
          "per bin")
    if not args.skip_localization:
        report["localization"] = loc = localization(args.session, args.poses)
        o = loc["overall"]
        print(f"CLEAN-SC localization, 5-15 kHz, 6 mm grid, {o['count']} (recording, band) "
              f"pairs: mean {o['mean_mm']:.2f} mm sub-grid, {o['mean_node_mm']:.2f} mm at "
              f"the grid node (paper: 6.6 mm) in {loc['time_s']:.1f} s")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(args.out.name + ".partial")
    tmp.write_text(json.dumps(report, indent=1))
    os.replace(tmp, args.out)


if __name__ == "__main__":
    main()
