"""The guesses of daq/usb/_unpublished.py as the emulated driver sends them, pinned.

This is the template docs/usb-protocol.md ("Correcting the guesses", step 7) asks a lab to
fill in: after `micam daq trace diff` of a capture of Data Translation's software, change the
guess in `_unpublished.py`, write here the values the capture showed (and name the capture:
date, board, serial, software, scan), and this test holds the driver to them. Until then the
values below are the guesses themselves, so a change to a guess cannot go unnoticed.
"""

from __future__ import annotations

from pathlib import Path

from daq import InputChannel, ScanConfig
from daq.usb import TransferTrace
from daq.usb.bringup import decode, read_transfers
from sim.usb import LoopbackBench, emulated_boards

SOURCE = "the guesses (no capture yet)"
"""Where the values come from, e.g. "vendor-ai.pcapng, 2026-05-04, DT9836-12-2 serial 12345,
QuickDAQ 3.7: 12 inputs, 96 kS/s, 9600 samples, internal clock, software trigger"."""
SCAN = ScanConfig(inputs=tuple(InputChannel(channel=c) for c in range(12)),
                  sample_rate_hz=96_000.0, samples_per_channel=9600)
SCAN_SETUP = {"MISC_CTRLS": 0x0003, "INPUT_CONTROL0": 0x0001, "INPUT_CHAN_MASK_LO": 0x0FFF,
              "INPUT_CHAN_MASK_HI": 0x0000, "SAMPLES_PER_TRIG_LO": 9600,
              "SAMPLES_PER_TRIG_HI": 0x0000, "IN_SAMPLE_CLK_PERIOD_LO": 375,
              "IN_SAMPLE_CLK_PERIOD_HI": 0x0000}
"""Register -> value the scan set-up writes (`trace show`: the W_*_WORD_LB before the arm)."""
SEQUENCE = ["W_SINGLE_WORD_LB IO_OP_CONTROL = 0x0020 (INPUT_SCAN_ARM)",
            "START_SUBSYSTEM AD ExtTrig 0x0000",
            "W_SINGLE_WORD_LB IO_OP_CONTROL = 0x0008 (INPUT_SOFT_TRIGGER)",
            "STOP_SUBSYSTEM AD ExtTrig 0x0000",
            "W_SINGLE_WORD_LB IO_OP_CONTROL = 0x0010 (INPUT_SCAN_STOP)"]
"""The commands from the arm to the stop, as `trace show` prints them."""
STREAM = "stream in 0x82: 1 transfers, 230400 bytes = 9600 frames of 12 channels"
"""How the input stream arrives (transfers depend on the host's read size: keep the frames)."""


def test_the_driver_scans_as_pinned(tmp_path: Path) -> None:
    with TransferTrace(tmp_path / "trace.jsonl") as trace:
        [board] = emulated_boards(LoopbackBench(), [("DT9836-12-2", "1")], trace=trace)
        board.configure(SCAN)
        board.arm()
        board.start()
        board.read(9600, timeout_s=5.0)
        board.stop()
        board.close()
    events = [e for e in decode(read_transfers(tmp_path / "trace.jsonl")) if e.kind != "poll"]
    writes = {w["register"]: w["value"] for e in events for w in e.fields.get("writes", [])}
    assert {r: writes.get(r) for r in SCAN_SETUP} == SCAN_SETUP, SOURCE
    arm = next(i for i, e in enumerate(events) if e.text == SEQUENCE[0])
    commands = [e.text for e in events[arm:] if e.kind == "command"]
    assert commands == SEQUENCE, SOURCE
    [stream] = [e.text for e in events if e.kind == "stream"]
    frames = STREAM.split(" = ")[1]
    assert stream.split(" = ")[1].startswith(frames), SOURCE
