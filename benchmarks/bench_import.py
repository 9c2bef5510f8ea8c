"""Any rig, any recorder (issue 13): a foreign lab's folder imported and calibrated, against
micam's own capture of the same world, over several seeds.

The foreign lab (sim/foreign_lab.py, acoustics of its own): 48 microphones on
8 boards x 6 channels, one camera, the opposite colour convention, the reference microphone on
board 0 in the reference recordings only, a known temperature, 6 poses (36 sources). The native
capture: the same microphones, camera, rig, poses and air through micam's capture sequencer on
simulated boards, the reference microphone on its own board on every burst. Both calibrated
with the joint fit. Printed, and written as JSON to benchmarks/results/import.json.

    .venv/bin/python benchmarks/bench_import.py [--seeds 1 2 3 4 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' foreign lab

from acquisition.importer import import_session
from calibration.pipeline import calibrate
from calibration.result import compare_with_truth
from sim import foreign_lab
from tests.calibration import foreign_rig


def measure_seed(seed: int, root: Path) -> dict[str, float]:
    world = foreign_lab.make_world(seed)
    toml = foreign_lab.write_folder(world, root / "lab")
    import_session(toml, root / "imported")
    native_truth = foreign_rig.same_world_natively(world, root / "native")
    out: dict[str, float] = {}
    for name, session, truth in (("import", root / "imported", world.truth()),
                                 ("native", root / "native", native_truth)):
        result = calibrate(session).result
        joint = compare_with_truth(result, truth)
        frozen = compare_with_truth(result, truth, camera_frozen=True)
        out[f"{name}_mean_mic_error_mm"] = 1e3 * joint["mean_mic_error_m"]
        out[f"{name}_frozen_mean_mic_error_mm"] = 1e3 * frozen["mean_mic_error_m"]
        out[f"{name}_speed_of_sound_error_m_s"] = joint["speed_of_sound_error_m_s"]
    out["ratio_import_native"] = (out["import_mean_mic_error_mm"]
                                  / out["native_mean_mic_error_mm"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args()
    rows = {}
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            rows[seed] = measure_seed(seed, Path(tmp))
        r = rows[seed]
        print(f"seed {seed}: import {r['import_mean_mic_error_mm']:.3f} mm (frozen "
              f"{r['import_frozen_mean_mic_error_mm']:.3f}), native "
              f"{r['native_mean_mic_error_mm']:.3f} mm (frozen "
              f"{r['native_frozen_mean_mic_error_mm']:.3f}), ratio "
              f"{r['ratio_import_native']:.2f}; c error import "
              f"{r['import_speed_of_sound_error_m_s']:+.3f}, native "
              f"{r['native_speed_of_sound_error_m_s']:+.3f} m/s")
    results = Path(__file__).parent / "results"
    results.mkdir(exist_ok=True)
    (results / "import.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
