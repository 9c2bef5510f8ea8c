"""The emulated USB bus: boards on ports, each showing its loader or its running face.

A board starts in loader state (FX2 boot ROM, loader product id) or, when the bus is built with
`firmware_loaded=True`, as if a previous session had already downloaded the firmware. A
re-enumeration or an unplug bumps the board's generation: pyusb device objects of the old
generation then fail with "No such device", as on a real bus.
"""

from __future__ import annotations

import itertools
import threading
import zlib
from collections.abc import Sequence
from typing import TYPE_CHECKING

from daq import BoardModel, ConfigurationError, board_model
from daq.usb._families import Family, family_named
from daq.usb._ids import (
    EP_CMD_OUT,
    EP_STREAM_OUT,
    FX2_REQUEST_EXTERNAL,
    FX2_REQUEST_INTERNAL,
    VENDOR_OUT,
)
from sim.analog_bench import AnalogBench

from ._clock import SharedClock
from ._descriptors import DeviceDescriptor
from ._errors import stall
from ._faults import Fault
from ._firmware import RunningFirmware
from ._fx2 import Fx2BootRom, StallRequest

if TYPE_CHECKING:
    from ._backend import EmulatedBackend


def eeprom_serial(serial: str) -> int:
    """The 32-bit number an emulated board's EEPROM holds for `serial`: the number itself for
    a decimal serial (as on real boards), else the CRC-32 of the text, so that the simulated
    layouts' names ("SIM3600") still give distinct boards."""
    if serial.isdigit() and int(serial) < 2**32:
        return int(serial)
    return zlib.crc32(serial.encode())


class EmulatedBoard:
    """One board plugged into the emulated bus; `serial` is its name on the bench."""

    def __init__(self, model: BoardModel, serial: str, port: int, bench: AnalogBench,
                 clock: SharedClock, faults: Sequence[Fault], addresses: itertools.count,
                 firmware_loaded: bool) -> None:
        self.model = model
        self.serial = serial
        self.port = port
        self.family: Family = family_named(model.name)
        self.bench, self.clock, self.faults = bench, clock, list(faults)
        self._addresses = addresses
        self.lock = threading.RLock()
        self.present = True
        self.generation = 0
        self.boot: Fx2BootRom | None = None
        self.firmware: RunningFirmware | None = None
        if firmware_loaded:
            self._run(self.family.running_pid)
        else:
            self.boot = Fx2BootRom()
            self.descriptor = DeviceDescriptor(self.family.loader_pid, next(addresses), port)

    @property
    def running(self) -> bool:
        return self.firmware is not None

    def unplug(self) -> None:
        """Pull the cable: the board leaves the bus for good."""
        with self.lock:
            self.present = False
            self.generation += 1

    def control_out(self, request_type: int, request: int, value: int, data: bytes) -> None:
        """A control transfer to the device: only the FX2 loader requests are answered."""
        if self.boot is None or request_type != VENDOR_OUT:
            raise stall()
        try:
            if request == FX2_REQUEST_INTERNAL:
                product_id = self.boot.write_internal(value, data)
                if product_id is not None:
                    self._reenumerate(product_id)
            elif request == FX2_REQUEST_EXTERNAL:
                self.boot.write_external(value, data)
            else:
                raise StallRequest(f"vendor request 0x{request:02x}")
        except StallRequest:
            raise stall() from None

    def bulk_write(self, endpoint: int, data: bytes) -> None:
        if self.firmware is None:
            raise stall()
        if endpoint == EP_CMD_OUT:
            self.firmware.command(data)
        elif endpoint == EP_STREAM_OUT:
            self.firmware.write_stream(data)
        else:
            raise stall()

    def _reenumerate(self, product_id: int) -> None:
        """The downloaded firmware starts: the board drops off and returns with its new id.

        A firmware announcing another id than the family's running id (the wrong image) never
        comes back: the driver's wait for re-enumeration reports it.
        """
        with self.lock:
            self.generation += 1
            self.boot = None
            if product_id == self.family.running_pid:
                self._run(product_id)
            else:
                self.present = False

    def _run(self, product_id: int) -> None:
        version = next(v for v, name in self.family.variants.items() if name == self.model.name)
        self.firmware = RunningFirmware(self.model, self.serial, eeprom_serial(self.serial),
                                        version, product_id,
                                        self.bench, self.clock, self.faults, self.unplug)
        self.descriptor = DeviceDescriptor(product_id, next(self._addresses), self.port)


class EmulatedBus:
    """Emulated Data Translation boards on one bus, sharing one bench, clock and trigger.

    Args:
        bench: the simulated analog world the boards sample and play into.
        boards: (model name, serial) per board; the serial is the board's name on the bench,
            and the driver reads `eeprom_serial(serial)` from the board.
        faults: faults to inject (see `Fault`).
        firmware_loaded: start with the firmware running (else in FX2 loader state, so the
            driver must download it).
        realtime: pace the shared clock in wall time (else as fast as the driver reads).
    """

    def __init__(self, bench: AnalogBench, boards: Sequence[tuple[str, str]],
                 faults: Sequence[Fault] = (), firmware_loaded: bool = True,
                 realtime: bool = False) -> None:
        self.clock = SharedClock(bench, realtime)
        addresses = itertools.count(2)
        self.boards: list[EmulatedBoard] = []
        numbers = [eeprom_serial(serial) for _, serial in boards]
        if len(set(numbers)) != len(numbers):
            raise ConfigurationError(f"two emulated boards share a serial number: {boards}")
        for port, (name, serial) in enumerate(boards, start=1):
            mine = [f for f in faults if f.serial == serial]
            self.boards.append(EmulatedBoard(board_model(name), serial, port, bench,
                                             self.clock, mine, addresses, firmware_loaded))
        unknown = {f.serial for f in faults} - {b.serial for b in self.boards}
        if unknown:
            raise ConfigurationError(f"faults name serials not on the bus: {sorted(unknown)}")

    @property
    def backend(self) -> EmulatedBackend:
        """The pyusb backend to pass to `usb.core.find` / `daq.usb.open_boards`."""
        from ._backend import EmulatedBackend

        return EmulatedBackend(self)
