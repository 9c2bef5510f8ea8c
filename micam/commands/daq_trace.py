"""`micam daq trace show|diff` and `micam daq probe`: the hardware bring-up kit.

`trace show` decodes a usbmon or USBPcap capture (pcap, pcapng) or a micam transfer trace with
the driver's protocol module; `trace diff` compares two of them and names the guess of
daq/usb/_unpublished.py each difference contradicts; `probe` reads a board's ids, descriptors,
version register and EEPROM, never writing, and writes a report and a trace to attach to a bug
report. The library is `daq.usb.bringup`; docs/usb-protocol.md has the procedure.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from acquisition.contracts.errors import UserError

from ..outputs import check_outputs

from .bounded import number

TRACE_SECONDS = number(0, 1e7, " s")
"""`trace show --from/--to`: seconds after the first record (up to 116 days)."""


def register(actions: argparse._SubParsersAction, emulated_backend: Callable[[], Any]) -> None:
    """Add `trace` and `probe` to the `micam daq` actions; `emulated_backend` builds the bus
    `--emulate` probes."""
    trace = actions.add_parser(
        "trace", help="decode and compare USB captures and micam transfer traces",
        description="Decode a usbmon / USBPcap capture or a micam transfer trace, or compare "
                    "two (docs/usb-protocol.md, 'Correcting the guesses').")
    sub = trace.add_subparsers(dest="trace_command", required=True, metavar="ACTION")
    show = sub.add_parser("show", help="every transfer decoded: commands, replies, streams",
                          description="Every transfer of FILE decoded with the driver's "
                                      "protocol: firmware download, commands and replies by "
                                      "name, registers by name, messages, stream summaries.")
    show.add_argument("file", type=Path, metavar="FILE",
                      help="a usbmon or USBPcap capture (pcap or pcapng) or a micam trace")
    who = show.add_mutually_exclusive_group()
    who.add_argument("--device", type=_device, metavar="BUS:ADDR",
                     help="only this device (bus number and device address, as lsusb shows)")
    who.add_argument("--serial", type=_serial, metavar="SERIAL",
                     help="only the board with this EEPROM serial")
    show.add_argument("--from", dest="start", type=TRACE_SECONDS, metavar="S",
                      help="from this many seconds after the first record")
    show.add_argument("--to", dest="end", type=TRACE_SECONDS, metavar="S",
                      help="up to this many seconds after the first record")
    show.add_argument("--polls", action="store_true",
                      help="also the empty reads of the stream and message endpoints")
    show.add_argument("--json", action="store_true",
                      help="one JSON object per decoded event and line")
    show.set_defaults(run=run_show)
    diff = sub.add_parser("diff", help="compare two traces, naming the guesses they contradict",
                          description="Align trace B (e.g. micam) with trace A (e.g. the "
                                      "vendor's software) by their command sequence; report "
                                      "every difference and the entry of "
                                      "daq/usb/_unpublished.py it contradicts. Exit status 1 "
                                      "if they differ.")
    diff.add_argument("a", type=Path, metavar="A", help="the reference trace or capture")
    diff.add_argument("b", type=Path, metavar="B", help="the trace or capture to compare")
    diff.add_argument("--serial", type=_serial, metavar="SERIAL",
                      help="only the board with this EEPROM serial, in both")
    diff.add_argument("--json", action="store_true", help="print the comparison as JSON")
    diff.set_defaults(run=run_diff)
    probe = actions.add_parser(
        "probe", help="read-only look at every board: ids, descriptors, version, EEPROM",
        description="Read each board's USB ids and descriptors, VERSION_ID register and "
                    "EEPROM; never writes a register, starts a scan or loads firmware. "
                    "Writes a report (JSON) and a transfer trace into --out.")
    probe.add_argument("--out", type=Path, default=Path("."), metavar="DIR",
                       help="directory for micam-probe-TIME.json and .trace.jsonl (default .)")
    probe.add_argument("--emulate", action="store_true",
                       help="probe emulated boards instead of the USB bus")
    probe.add_argument("--json", action="store_true", help="print the report as JSON")
    probe.set_defaults(run=run_probe, emulated_backend=emulated_backend)


def _device(text: str) -> str:
    m = re.fullmatch(r"(\d{1,5}):(\d{1,3})", text)
    if not m or int(m.group(1)) > 0xFFFF or int(m.group(2)) > 127:
        raise argparse.ArgumentTypeError(f"{text!r} is not BUS:ADDR (e.g. 1:5)")
    return f"{int(m.group(1))}:{int(m.group(2))}"


def _serial(text: str) -> str:
    if not text.isdigit() or int(text) >= 2**32:
        raise argparse.ArgumentTypeError(f"{text!r} is not a board serial (a decimal number)")
    return str(int(text))


def run_show(args: argparse.Namespace) -> int:
    from daq.usb.bringup import Decoder, Selection, TraceError, read_transfers, select

    if args.start is not None and args.end is not None and args.end < args.start:
        raise UserError(f"--to {args.end} is before --from {args.start}")
    decoder = Decoder()

    def events() -> Iterator[Any]:
        for tr in read_transfers(args.file):
            yield from decoder.feed(tr)
        yield from decoder.finish()

    selection = Selection(device=args.device, serial=args.serial, start=args.start,
                          end=args.end)
    shown = 0
    try:
        for event in select(events(), decoder, selection):
            if event.kind == "poll" and not args.polls:
                continue
            shown += 1
            if args.json:
                print(json.dumps(event.as_json()))
            else:
                print(f"{event.t:11.6f} {event.device:>6s} {event.kind:8s} {event.text}")
    except TraceError as exc:
        raise UserError(str(exc)) from None
    if not args.json:
        hidden = "" if args.polls else f" ({decoder.polls} empty polls hidden: --polls)"
        print(f"{decoder.transfers} transfers, {shown} events shown{hidden}")
        for info in decoder.devices.values():
            print(f"device {info.label()}")
    return 0


def run_diff(args: argparse.Namespace) -> int:
    from daq.usb.bringup import TraceError, diff_traces

    try:
        result = diff_traces(args.a, args.b, serial=args.serial)
    except TraceError as exc:
        raise UserError(str(exc)) from None
    if args.json:
        print(json.dumps({"a": str(result.a), "b": str(result.b),
                          "boards": [list(p) for p in result.pairs],
                          "differences": [d.as_json() for d in result.differences],
                          "summary": result.summary()}))
        return 1 if result.differences else 0
    print(f"A: {result.a}\nB: {result.b}")
    for a, b in result.pairs:
        print(f"board: {a}  <->  {b}")
    if not result.differences:
        print("no differences")
        return 0
    first, *later = result.differences
    print(f"first difference: {first.text()}")
    for n, d in enumerate(later, start=2):
        print(f"{n:4d}. {d.text()}")
    summary = ", ".join(f"{basis}: {n}" for basis, n in result.summary().items())
    print(f"summary: {len(result.differences)} differences; {summary}")
    return 1


def run_probe(args: argparse.Namespace) -> int:
    import usb.core

    from daq.usb import TransferTrace
    from daq.usb.bringup import probe

    out: Path = args.out
    stem = out / time.strftime("micam-probe-%Y%m%d-%H%M%S")
    report_path, trace_path = stem.with_suffix(".json"), stem.with_suffix(".trace.jsonl")
    check_outputs(("--out", report_path))  # makes a missing --out directory
    for path in (report_path, trace_path):
        if path.exists():
            raise UserError(f"{path} exists; wait a second or choose another --out")
    backend = args.emulated_backend() if args.emulate else None
    try:
        with TransferTrace(trace_path) as trace:
            report = probe(backend, trace)
    except (usb.core.NoBackendError, usb.core.USBError) as exc:
        trace_path.unlink(missing_ok=True)
        raise UserError(f"cannot scan the USB bus: {exc}. Is libusb-1.0 installed (Debian: "
                        "libusb-1.0-0), and may this user open the boards "
                        "(udev/README.md, `micam install udev`)?") from None
    except OSError as exc:
        raise UserError(f"cannot write {trace_path}: {exc.strerror or exc}") from None
    try:
        with report_path.open("x", encoding="utf-8") as f:
            f.write(report.model_dump_json(indent=2) + "\n")
    except OSError as exc:
        raise UserError(f"cannot write {report_path}: {exc.strerror or exc}") from None
    print(report.model_dump_json() if args.json else report.text())
    if not args.json:
        print(f"report: {report_path}\ntrace: {trace_path}")
    return 0 if report.boards else 1
