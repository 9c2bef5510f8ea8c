"""`micam simulate`: a capture session recorded by the real sequencer on the simulated world."""

from __future__ import annotations

import argparse
import signal
import sys
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING

from pydantic import ValidationError
from tqdm import tqdm

from acquisition.contracts.burst import MIN_STEADY_PERIOD_S
from acquisition.contracts.errors import UserError
from .bounded import BURST_PERIODS, MLS_ORDER, SEED, integer, number

from ..outputs import check_output_dirs

if TYPE_CHECKING:
    from acquisition.sequencer import Progress


def _mistakes_epilog() -> str:
    """The mistakes `--mistake` can ask for, one line each."""
    from sim.mistakes import KINDS

    width = max(len(k.usage) for k in KINDS) + 2
    lines = [f"  {k.usage:<{width}}{k.help}" for k in KINDS]
    return ("mistakes (--mistake NAME[=ARGS]): ARGS are positional numbers (micam's 0-based "
            "ids), each\nmay be left out from the right and is then drawn from --seed; "
            "truth.json's \"mistakes\" says\nwhat was done (docs/simulation.md, "
            "\"Mistakes\"):\n" + "\n".join(lines))


MISTAKES_EPILOG = "(the mistakes --mistake can ask for)"
"""The epilog's placeholder, replaced by `_mistakes_epilog()` when the help is formatted."""


class _MistakesHelp(argparse.RawDescriptionHelpFormatter):
    """Lists the mistakes only when the help is shown: they are the simulator's, which building
    the parser (for any command, `micam daemon` too) must not load."""

    def add_text(self, text: str | None) -> None:
        super().add_text(_mistakes_epilog() if text is MISTAKES_EPILOG else text)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="record a capture session on the simulated world",
        description=textwrap.fill(
            "Run the capture sequencer on simulated boards and cameras and write a session "
            "to DIR, with the simulation's ground truth in DIR/truth.json.", 79),
        epilog=MISTAKES_EPILOG,
        formatter_class=_MistakesHelp,
    )
    p.add_argument("--out", required=True, type=Path, metavar="DIR",
                   help="session directory (new or empty; with --resume, an interrupted one)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted session in DIR with its original settings")
    p.add_argument("--array", default="sphere72",
                   help="array layout: sphere72, planar64, scatter48 or scatter15 (15 "
                        "microphones and the reference: one 16-input audio interface; default "
                        "sphere72)")
    p.add_argument("--poses", type=integer(1, 10_000), default=20,
                   help="rig poses to capture (default 20)")
    p.add_argument("--distance", type=number(0.2, 5.0, " m"), nargs=2, default=(0.6, 1.0),
                   metavar=("MIN", "MAX"),
                   help="rig distance range from camera 0 in metres (default 0.6 1.0)")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the simulated world")
    p.add_argument("--noise", type=number(0, 100), default=1.0,
                   help="scale of all noise: 1 = a real lab (default), 0 = none")
    p.add_argument("--temperature", type=number(-40, 60, " degC"), default=20.0,
                   help="air temperature, degC")
    p.add_argument("--mls-order", type=MLS_ORDER, default=14,
                   help="MLS order of the bursts (14 = 171 ms at 96 kS/s)")
    p.add_argument("--mls-periods", type=BURST_PERIODS, default=None,
                   help="periods of the MLS per burst (default: 2, whose last, correlated "
                        "circularly, keeps a room's reflections off the direct sound; 1 for "
                        f"sequences shorter than {1e3 * MIN_STEADY_PERIOD_S:g} ms)")
    p.add_argument("--body-diffraction", action="store_true",
                   help="sound reaches microphones behind a sphere array around its surface")
    p.add_argument("--lab", choices=("ideal", "realistic"), default="ideal",
                   help="the lab: 'ideal' (default) or 'realistic' (speaker acoustic centres, "
                        "rig tolerance, print scale, microphone responses, air drift, room, "
                        "ambient noise, directivity, air sensor, and the cameras' effects; "
                        "docs/simulation.md)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME",
                   help="add one lab effect to the profile (repeatable): acoustic-centres, "
                        "rig-tolerance, print-scale, mic-responses, air-drift, room, "
                        "ambient-noise, directivity, air-sensor; the cameras': sensor-noise, "
                        "fixed-pattern, defocus, lens-distortion, vignetting, lighting, "
                        "board-bow, gamma")
    p.add_argument("--without", action="append", default=[], metavar="NAME",
                   help="remove one lab effect from the profile (repeatable)")
    p.add_argument("--mistake", action="append", default=[], metavar="NAME[=ARGS]",
                   help="a mistake the simulated world makes (repeatable; the list below), "
                        "e.g. swap-mics=12,13; the session's configuration stays the nominal "
                        "one")
    p.add_argument("--backend", choices=("sim", "usb-emulated", "audio"), default="sim",
                   help="plain simulated boards (default), the real USB driver on emulated "
                        "USB boards, or the audio backend on a running JACK server with the "
                        "world as a JACK client (docs/hardware.md; --array scatter15)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


def _options_from_args(args: argparse.Namespace):
    from sim.capture import SimulationOptions

    try:
        return SimulationOptions(
            array=args.array, poses=args.poses, distance_m=tuple(args.distance), seed=args.seed,
            noise=args.noise, temperature_c=args.temperature, mls_order=args.mls_order,
            mls_periods=args.mls_periods, body_diffraction=args.body_diffraction,
            backend=args.backend, lab=args.lab,
            effects=tuple(args.effect), without_effects=tuple(args.without),
            mistakes=tuple(args.mistake),
        )
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(map(str, e['loc']))}: {e['msg']}" if e["loc"]
            else str(e["msg"]).removeprefix("Value error, ") for e in exc.errors())
        raise UserError(f"invalid simulation options: {problems}") from None


class Terminated(Exception):
    """SIGTERM arrived during the capture: it ends as interrupted, resumable (exit status 3,
    README "Exit status"), not killed by the signal (143)."""


def _terminate(_signum: int, _frame: object) -> None:
    raise Terminated("terminated (SIGTERM)")


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


def run(args: argparse.Namespace) -> int:
    from acquisition.contracts.camera import CameraError
    from acquisition.contracts.session import SessionError, SessionExistsError
    from micam.simulated import TRUTH_FILE, prepare_simulated_capture
    from daq import DaqError

    out: Path = args.out
    if not args.resume:
        check_output_dirs(("--out", out), session_hint="continue an interrupted one with "
                          f"`micam simulate --resume --out {out}`, or ")
    options = None if args.resume else _options_from_args(args)
    try:
        sim, sequencer = prepare_simulated_capture(out, options)
    except SessionExistsError:
        raise UserError(f"{out} already holds a session, which is never overwritten: continue "
                        f"an interrupted one with `micam simulate --resume --out {out}`, or "
                        "choose a new --out") from None
    except (SessionError, FileNotFoundError) as exc:
        raise UserError(str(exc)) from None
    except OSError as exc:  # the directory cannot be made: read-only, no permission, full
        raise UserError(f"cannot create the session {out}: {exc}; choose a --out on a "
                        "writable disk with free space") from None
    remaining = len(sequencer.remaining_steps())
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        with tqdm(total=remaining, unit="step", disable=args.quiet, desc="capture") as bar:
            def progress(p: Progress) -> None:
                bar.set_postfix_str(p.step)
                bar.update(1)

            sequencer.on_progress = progress
            sequencer.run()
    except (DaqError, CameraError, SessionError, OSError, Terminated) as exc:
        print(f"micam: capture interrupted: {_first_line(exc)}\n"
              f"Every completed step in {out} is safe; fix the cause (for a full or read-only "
              f"disk: free space, or make it writable) and continue with\n"
              f"  micam simulate --resume --out {out}", file=sys.stderr)
        return 3
    finally:
        signal.signal(signal.SIGTERM, previous)
        sequencer.writer.close()
    if not args.quiet:
        print(f"session written to {out} ({sim.options.poses} poses, "
              f"{len(sim.config.speakers)} speakers, {len(sim.config.columns)} channels); "
              f"ground truth in {out / TRUTH_FILE}")
    return 0
