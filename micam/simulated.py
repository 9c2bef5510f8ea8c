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

from pydantic import ValidationError

from sim.backends import build_capture
from sim.capture import SimulatedCapture, SimulationOptions, truth_document

from acquisition.sequencer import CaptureSequencer, Progress
from acquisition.contracts.session import SessionError, SessionWriter, write_atomic

TRUTH_FILE = "truth.json"


def _write_json_atomic(path: Path, data: dict) -> None:
    text = json.dumps(data, indent=1).encode()
    write_atomic(path, lambda fh: fh.write(text), replace=True)


MAX_TRUTH_BYTES = 256 * 1024 * 1024
"""The largest truth.json `--resume` reads (10 000 poses, the most a simulation takes, write
a few tens of MB)."""


def _resumed_options(truth_path: Path) -> SimulationOptions:
    """The options a simulated session was started with, from its truth.json: a file anyone
    who can write the session may have changed, so SessionError for one that is too large,
    not JSON, or whose options are not valid, and FileNotFoundError for none."""
    if not truth_path.is_file():
        raise FileNotFoundError(
            f"{truth_path.parent} holds no simulated session ({TRUTH_FILE} is missing); only "
            "sessions made by `micam simulate` can be resumed this way")
    why = f"{truth_path} cannot be resumed from"
    if truth_path.stat().st_size > MAX_TRUTH_BYTES:
        raise SessionError(f"{why}: it is larger than {MAX_TRUTH_BYTES >> 20} MiB")
    try:
        document = json.loads(truth_path.read_bytes())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
        document = None
    simulation = document.get("simulation") if isinstance(document, dict) else None
    if not isinstance(simulation, dict):
        raise SessionError(f"{why}: it is not a JSON object with the simulation's options "
                           "(\"simulation\"); it was changed or not written by micam simulate")
    try:
        return SimulationOptions(**simulation)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(map(str, first["loc"]))
        raise SessionError(f"{why}: its simulation option {where or '(all)'} is not valid "
                           f"({first['msg']}); it was changed or written by another version of "
                           "micam") from None


def prepare_simulated_capture(out: Path, options: SimulationOptions | None,
                              ) -> tuple[SimulatedCapture, CaptureSequencer]:
    """A sequencer ready to run: a new session in `out` for `options`, or (options None) the
    interrupted simulated session in `out` resumed with the options it was started with.

    Raises SessionError (the directory holds a session already, or none to resume; its
    truth.json is not one `micam simulate` wrote; or the new session's truth.json cannot be
    written, in which case the session, which holds no recording yet, is removed again),
    FileNotFoundError (resuming a directory without truth.json), SimulationInputError (its
    options describe no world) and OSError (the directory cannot be created).
    """
    if options is None:
        options = _resumed_options(out / TRUTH_FILE)
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
