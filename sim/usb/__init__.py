"""Emulated Data Translation boards behind a pyusb backend of our own.

The real USB driver (`daq.usb`) runs unchanged on these boards: they enumerate with the loader
id, take the FX2 firmware download, re-enumerate with the running id, parse the command packets,
keep a register file, stream input samples computed by an `AnalogBench` on the shared clock,
play the output stream into the bench as the speaker signal, and inject faults on request.

`emulated_boards` is what `micam simulate --backend usb-emulated` calls; tests that need the
bus itself (to unplug a board, say) build an `EmulatedBus` and call `daq.usb.open_boards`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from daq import Board
from daq.usb import TransferTrace, open_boards, write_ihex
from daq.usb._families import FAMILIES, LOADER_IMAGE
from sim.analog_bench import AnalogBench

from ._backend import EmulatedBackend
from ._bus import EmulatedBoard, EmulatedBus, eeprom_serial
from ._descriptors import device_descriptor_bytes
from ._faults import Fault, FaultKind
from .loopback import LoopbackBench

__all__ = [
    "EmulatedBackend",
    "EmulatedBoard",
    "EmulatedBus",
    "Fault",
    "FaultKind",
    "LoopbackBench",
    "eeprom_serial",
    "emulated_boards",
    "synthetic_firmware",
]


def emulated_boards(bench: AnalogBench, boards: Sequence[tuple[str, str]],
                    firmware_dir: Path | None = None, faults: Sequence[Fault] = (),
                    realtime: bool = False, trace: TransferTrace | None = None) -> list[Board]:
    """Build an emulated bus and open its boards through the real driver.

    Args:
        bench: the simulated world the boards are wired to.
        boards: (model name, serial) per board, e.g. [("DT9836-12-2", "1001")]. The serial
            names the board on the bench; the driver reads `eeprom_serial(serial)` from the
            board (the number itself for a decimal serial, as real boards hold 32-bit serials;
            a CRC-32 for a name such as "SIM3600"), which is the returned boards' serial.
        firmware_dir: None starts the boards with their firmware already running; a directory
            (see `synthetic_firmware`) starts them in FX2 loader state, and the driver
            downloads the images from it.
        faults: faults to inject (see `Fault`).
        realtime: pace the shared clock in wall time (for CPU-load figures).
        trace: write every USB transfer to this trace.
    Returns:
        Driver boards (`daq.usb.UsbBoard`), in the order of `boards`.
    """
    bus = EmulatedBus(bench, boards, faults, firmware_loaded=firmware_dir is None,
                      realtime=realtime)
    return list(open_boards([str(eeprom_serial(s)) for _, s in boards], backend=bus.backend,
                            firmware_dir=firmware_dir, trace=trace, reenumerate_timeout_s=2.0))


def synthetic_firmware(directory: Path) -> Path:
    """Write stand-in firmware images (Intel HEX) that the emulated FX2 accepts.

    They hold no 8051 code, only what the emulator looks at: a loader image with some internal
    RAM and no descriptor, and per family an image whose external RAM carries the device
    descriptor with the family's running id (where Data Translation's DT9836 image has it).
    """
    directory.mkdir(parents=True, exist_ok=True)
    write_ihex(directory / f"{LOADER_IMAGE}.hex", [(0x0000, bytes(range(1, 200)))])
    for family in FAMILIES:
        write_ihex(directory / f"{family.firmware}.hex", [
            (0x0000, bytes([0x02, 0x01, 0x00]) + bytes(61)),
            (0x5B94, device_descriptor_bytes(family.running_pid)),
        ])
    return directory
