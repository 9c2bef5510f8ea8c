"""The emulated Cypress FX2 boot ROM: RAM writes, CPUCS, and re-enumeration.

It answers vendor request 0xA0 (internal RAM and CPUCS) always, and 0xA3 (external RAM) only
while a loader runs. Releasing CPUCS starts the 8051 on whatever RAM holds: if RAM holds a
Data Translation device descriptor, the "firmware" announces that product id (the board
re-enumerates); otherwise the code is taken to be the second-stage loader, which answers 0xA3.
No 8051 code is run; the descriptor inside the image is what decides, as on the real chip.
"""

from __future__ import annotations

from daq.usb._ids import FX2_CPUCS, FX2_INTERNAL_RAM_END

from ._descriptors import find_device_descriptor


class StallRequest(Exception):
    """The device refuses a control request (a STALL handshake)."""


class Fx2BootRom:
    """RAM and reset state of one FX2 in loader state."""

    def __init__(self) -> None:
        self.ram = bytearray(0x10000)
        self.in_reset = True
        self.loader_running = False

    def write_internal(self, address: int, data: bytes) -> int | None:
        """0xA0: write internal RAM or CPUCS; returns the product id to re-enumerate with, if
        releasing the CPU started a firmware image."""
        if address == FX2_CPUCS:
            if len(data) != 1:
                raise StallRequest("CPUCS takes one byte")
            return self._cpucs(data[0] & 1 == 1)
        if address + len(data) - 1 > FX2_INTERNAL_RAM_END:
            raise StallRequest("0xA0 reaches beyond internal RAM")
        self.ram[address: address + len(data)] = data
        return None

    def write_external(self, address: int, data: bytes) -> None:
        """0xA3: write external RAM, only while the second-stage loader runs."""
        if not self.loader_running:
            raise StallRequest("0xA3 needs the loader running")
        if address + len(data) > len(self.ram):
            raise StallRequest("0xA3 beyond the address space")
        self.ram[address: address + len(data)] = data

    def _cpucs(self, hold: bool) -> int | None:
        self.in_reset = hold
        if hold:
            self.loader_running = False
            return None
        product_id = find_device_descriptor(bytes(self.ram))
        if product_id is None:
            self.loader_running = any(self.ram[: FX2_INTERNAL_RAM_END + 1])
        return product_id
