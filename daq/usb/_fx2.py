"""The Cypress FX2 firmware download (public facts: FX2 reference, ezusb.c, uldaq).

A board without firmware enumerates with its loader product id and answers only the FX2 boot
ROM's vendor request 0xA0 (write internal RAM, including the CPUCS reset register). The DT9836
image lies mostly in external RAM, so a small second-stage loader (`a3load`) is downloaded and
started first; it answers 0xA3 (write external RAM). Order, as in Data Translation's driver:
hold reset, write the loader to internal RAM, release reset; write the device image's external
part with 0xA3; hold reset; write its internal part with 0xA0; release reset. The board then
disconnects and re-enumerates with its running product id, at the same bus port.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import usb.core

from daq import DaqError

from ._errors import FirmwareError
from ._ids import (
    FX2_CPUCS,
    FX2_REQUEST_EXTERNAL,
    FX2_REQUEST_INTERNAL,
    VENDOR_ID,
    VENDOR_OUT,
)
from ._images import FirmwareImage
from ._transport import UsbTransport

CHUNK_BYTES = 1023
"""Largest RAM write per control transfer (as fxload)."""
REQUEST_TIMEOUT_S = 3.0
"""Timeout of one loader control transfer (Data Translation's driver: 3 s)."""


def download(transport: UsbTransport, loader: FirmwareImage, image: FirmwareImage) -> None:
    """Download the loader and the device image; the board re-enumerates afterwards."""
    _reset(transport, hold=True)
    _write(transport, FX2_REQUEST_INTERNAL, loader.internal())
    _reset(transport, hold=False)
    _write(transport, FX2_REQUEST_EXTERNAL, image.external())
    _reset(transport, hold=True)
    _write(transport, FX2_REQUEST_INTERNAL, image.internal())
    try:
        _reset(transport, hold=False)
    except DaqError:
        pass  # the board may drop off the bus before acknowledging; re-enumeration tells


def wait_for_running(find: Callable[..., Iterable[usb.core.Device]], bus: int | None,
                     port_numbers: tuple[int, ...] | None, running_pid: int, where: str,
                     timeout_s: float) -> usb.core.Device:
    """Poll the bus until the board at (bus, port) shows its running id; FirmwareError if not."""
    deadline = time.monotonic() + timeout_s
    while True:
        for dev in find(find_all=True, idVendor=VENDOR_ID, idProduct=running_pid):
            if dev.bus == bus and tuple(dev.port_numbers or ()) == tuple(port_numbers or ()):
                return dev
        if time.monotonic() > deadline:
            raise FirmwareError(
                f"{where} did not re-enumerate as {VENDOR_ID:04x}:{running_pid:04x} within "
                f"{timeout_s:.0f} s of the firmware download: check that the images match the "
                "board, then replug it"
            )
        time.sleep(0.02)


def _reset(transport: UsbTransport, hold: bool) -> None:
    transport.control_out(FX2_REQUEST_INTERNAL, FX2_CPUCS, 0, bytes([1 if hold else 0]),
                          REQUEST_TIMEOUT_S, VENDOR_OUT)


def _write(transport: UsbTransport, request: int, segments: list[tuple[int, bytes]]) -> None:
    for address, data in segments:
        for off in range(0, len(data), CHUNK_BYTES):
            transport.control_out(request, address + off, 0, data[off: off + CHUNK_BYTES],
                                  REQUEST_TIMEOUT_S, VENDOR_OUT)
