"""A capture session recorded by the real sequencer on the simulated world.

Used by `micam simulate`, `micam study`, the benchmarks and the tests. The simulation's truth
goes beside the session's files in `truth.json` (written atomically at the start, because
`resume` rebuilds the same world from the options stored in it).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

from sim.backends import build_capture
from sim.capture import SimulatedCapture, SimulationOptions, truth_document

from acquisition.sequencer import CaptureSequencer, Progress
from acquisition.contracts.session import SessionError, SessionWriter, write_atomic

TRUTH_FILE = "truth.json"


def _write_json_atomic(path: Path, data: dict) -> None:
    text = json.dumps(data, indent=1).encode()
    write_atomic(path, lambda fh: fh.write(text), replace=True)


def prepare_simulated_capture(out: Path, options: SimulationOptions | None,
                              ) -> tuple[SimulatedCapture, CaptureSequencer]:
    """A sequencer ready to run: a new session in `out` for `options`, or (options None) the
    interrupted simulated session in `out` resumed with the options it was started with.

    Raises SessionError (the directory holds a session already, or none to resume; or the
    new session's truth.json cannot be written, in which case the session, which holds no
    recording yet, is removed again), FileNotFoundError (resuming a directory without
    truth.json) and OSError (the directory cannot be created).
    """
    if options is None:
        truth_path = out / TRUTH_FILE
        if not truth_path.is_file():
            raise FileNotFoundError(
                f"{out} holds no simulated session ({TRUTH_FILE} is missing); only sessions "
                "made by `micam simulate` can be resumed this way")
        options = SimulationOptions(**json.loads(truth_path.read_text())["simulation"])
        sim = build_capture(options)
        writer = SessionWriter.resume(out)
    else:
        sim = build_capture(options)
        writer = SessionWriter.create(out, capture=sim.config.model_dump(mode="json"))
        try:
            _write_json_atomic(out / TRUTH_FILE, truth_document(sim))
        except OSError as exc:  # without its truth the session could never be resumed
            writer.close()
            shutil.rmtree(out, ignore_errors=True)
            raise SessionError(f"cannot write {out / TRUTH_FILE} ({exc}); the new session was "
                               "removed again (it held no recording): fix the cause (disk "
                               "full? read-only?) and start again") from None
    return sim, CaptureSequencer(sim.config, sim.group, sim.cameras, sim.operator, writer,
                                 air_sensor=sim.air_sensor)


def record_simulated_session(out: Path, options: SimulationOptions,
                             on_progress: Callable[[Progress], None] | None = None) -> dict:
    """Capture a whole simulated session into `out`; returns its truth document."""
    sim, sequencer = prepare_simulated_capture(out, options)
    sequencer.on_progress = on_progress
    try:
        sequencer.run()
    finally:
        sequencer.writer.close()
    return truth_document(sim)
