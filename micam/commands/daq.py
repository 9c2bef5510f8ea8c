"""`micam daq list|selftest`: the boards on the USB bus, and a short scan on each
(`trace` and `probe`, the bring-up kit, are in `daq_trace`).

With `--emulate`, the same commands run the real driver against emulated boards (the
simulated 72-microphone sphere's ten boards), which is how they are tested here. With
`--backend audio`, they list the audio interfaces PortAudio reaches (host API, channel counts,
default rate) and scan every input of each (`--device` picks one).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from acquisition.contracts.errors import UserError
from .bounded import positive

from . import daq_trace


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("daq", help="list the boards and test them",
                       description="Data Translation boards on the USB bus, or (--backend "
                                   "audio) the audio interfaces PortAudio reaches.")
    actions = p.add_subparsers(dest="daq_command", required=True, metavar="ACTION")
    lst = actions.add_parser("list", help="boards found: model, serial, firmware state")
    test = actions.add_parser("selftest", help="a short scan on every board: rates and levels")
    test.add_argument("--seconds", type=positive(60, " s"), default=0.5,
                      help="scan length per board")
    test.add_argument("--firmware-dir", type=Path, default=None,
                      help="where the boards' firmware images are (else $MICAM_FIRMWARE_DIR)")
    for action in (lst, test):
        action.add_argument("--emulate", action="store_true",
                            help="use emulated boards instead of the USB bus")
        action.add_argument("--backend", choices=("usb", "audio"), default="usb",
                            help="usb: Data Translation boards (default); audio: the audio "
                                 "interfaces PortAudio reaches (ALSA, JACK, ...)")
    test.add_argument("--device", default=None, metavar="NAME",
                      help="with --backend audio: only this interface (a part of its name)")
    lst.set_defaults(run=run_list)
    test.set_defaults(run=run_selftest)
    daq_trace.register(actions, _emulated_backend)


def _emulated_backend() -> Any:
    from sim.arrays import sphere72
    from sim.analog_bench import AcousticBench
    from sim.usb import EmulatedBus
    from sim.world import World

    world = World(layout=sphere72())
    return EmulatedBus(AcousticBench(world), [(b.model, b.serial) for b in world.layout.boards]
                       ).backend


def _backend(args: argparse.Namespace) -> Any:
    return _emulated_backend() if args.emulate else None


def _audio_unusable(exc: Exception) -> UserError:
    return UserError(str(exc).splitlines()[0])


def run_audio_list() -> int:
    from daq import DaqError
    from daq.audio import list_devices

    try:
        devices = list_devices()
    except DaqError as exc:
        raise _audio_unusable(exc) from None
    if not devices:
        print("no audio interface found (is it plugged in; for JACK, is the server running?)")
        return 1
    print(f"{'host API':26s} {'inputs':>6s} {'outputs':>7s} {'rate':>8s}  name")
    for d in devices:
        print(f"{d.host_api:26s} {d.inputs:6d} {d.outputs:7d} {d.default_rate_hz:8.0f}  {d.name}")
    return 0


def run_audio_selftest(args: argparse.Namespace) -> int:
    import math

    from daq import DaqError, selftest
    from daq.audio import AudioBoard, find_device, list_devices

    try:
        devices = ([find_device(args.device)] if args.device is not None
                   else [d for d in list_devices() if d.inputs > 0])
    except DaqError as exc:
        raise _audio_unusable(exc) from None
    if not devices:
        print("no audio interface with inputs found")
        return 1
    failed = 0
    for device in devices:
        with AudioBoard(device, label=str(device.index)) as board:
            report = selftest(board, args.seconds)
        peak = max((max(abs(c.min_code), abs(c.max_code)) for c in report.channels), default=0)
        dbfs = 20 * math.log10(peak / 32768) if peak else -math.inf
        status = "ok" if report.ok else f"FAILED: {report.error}"
        print(f"{device}: {report.received}/{report.samples} samples on {len(report.channels)} "
              f"inputs at {rate_text(report.rate_hz)} ({_achieved(report.achieved_rate_hz)}), "
              f"peak {dbfs:.1f} dBFS: {status}")
        failed += not report.ok
    return 1 if failed else 0


def run_list(args: argparse.Namespace) -> int:
    if args.backend == "audio":
        return run_audio_list()
    import usb.core

    from daq.usb import list_boards

    try:
        boards = list_boards(_backend(args))
    except (usb.core.NoBackendError, usb.core.USBError) as exc:
        raise _usb_unusable(exc) from None
    if not boards:
        print("no Data Translation board found (check the cable, power and udev rules: "
              "udev/README.md, `micam install udev`)")
        return 1
    print(f"{'family':8s} {'model':12s} {'serial':>10s} {'firmware':9s} {'usb id':10s} location")
    for b in boards:
        state = "running" if b.firmware_loaded else "loader"
        print(f"{b.family:8s} {b.model or '?':12s} {b.serial or '?':>10s} {state:9s} "
              f"{b.usb_id:10s} {b.location}" + (f"  ({b.error})" if b.error else ""))
    return 0


def rate_text(hz: float) -> str:
    """A sample rate as a person reads it: "96 kS/s", "2.73 MS/s", "500 S/s"."""
    for scale, unit in ((1e6, "MS/s"), (1e3, "kS/s")):
        if hz >= scale:
            return f"{hz / scale:.3g} {unit}"
    return f"{hz:.0f} S/s"


def _achieved(hz: float, emulated: bool = False) -> str:
    """The rate a self-test's samples arrived at; an emulated board is not paced by a clock,
    so its rate says how fast this computer reads, not the board."""
    if emulated:
        return f"emulated, not paced: read at {rate_text(hz)}"
    return f"achieved {rate_text(hz)}"


def _usb_unusable(exc: Exception) -> UserError:
    return UserError(
        f"cannot scan the USB bus: {exc}. Is libusb-1.0 installed (Debian: libusb-1.0-0), "
        "and may this user open the boards (udev/README.md, `micam install udev`)?")


def run_selftest(args: argparse.Namespace) -> int:
    import usb.core

    from daq import DaqError
    from daq.usb import open_boards, selftest

    if args.backend == "audio":
        return run_audio_selftest(args)
    try:
        boards = open_boards(backend=_backend(args), firmware_dir=args.firmware_dir)
    except (usb.core.NoBackendError, usb.core.USBError) as exc:
        raise _usb_unusable(exc) from None
    except DaqError as exc:
        raise UserError(str(exc)) from None
    if not boards:
        print("no Data Translation board found")
        return 1
    failed = 0
    for board in boards:
        report = selftest(board, args.seconds)
        board.close()
        rms = [c.rms_v for c in report.channels]
        status = "ok" if report.ok else f"FAILED: {report.error}"
        print(f"{report.board}: {report.received}/{report.samples} samples at "
              f"{rate_text(report.rate_hz)} "
              f"({_achieved(report.achieved_rate_hz, args.emulate)}), "
              f"input RMS {min(rms, default=0):.4f}-{max(rms, default=0):.4f} V: {status}")
        failed += not report.ok
    return 1 if failed else 0
