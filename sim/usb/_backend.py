"""A pyusb backend (IBackend) whose devices are the emulated boards of an `EmulatedBus`.

pyusb accepts any object with the IBackend methods: `usb.core.find(backend=bus.backend)`.
The "dev" objects handed to pyusb name a board *and* its generation, so a pyusb Device found
before a re-enumeration or an unplug fails with "No such device" afterwards. Transfers use
pyusb's conventions: buffers are `array.array`, reads fill the buffer and return the count,
timeouts are in milliseconds, errors are `usb.core.USBError` with libusb's codes.
"""

from __future__ import annotations

import array
from dataclasses import dataclass
from typing import TYPE_CHECKING

from usb.backend import IBackend

from daq.usb._ids import INTERFACE

from ._descriptors import (
    CONFIGURATION,
    RUNNING_ENDPOINTS,
    ConfigurationDescriptor,
    DeviceDescriptor,
    EndpointDescriptor,
    InterfaceDescriptor,
)
from ._errors import no_device, stall

if TYPE_CHECKING:  # the bus builds its backend: at run time only the bus imports this module
    from ._bus import EmulatedBoard, EmulatedBus

_DIR_IN = 0x80


@dataclass(frozen=True)
class DeviceRef:
    """pyusb's opaque device (and handle): one board at one generation."""

    board: EmulatedBoard
    generation: int

    def live(self) -> EmulatedBoard:
        """The board, or "No such device" if it re-enumerated or left the bus since."""
        if not self.board.present or self.board.generation != self.generation:
            raise no_device()
        return self.board


class EmulatedBackend(IBackend):
    """The IBackend methods pyusb calls, answered by the emulated boards (interrupt and
    isochronous transfers keep IBackend's NotImplementedError: the boards have none)."""

    def __init__(self, bus: EmulatedBus) -> None:
        self.bus = bus

    # -- enumeration and descriptors --------------------------------------------------------

    def enumerate_devices(self) -> list[DeviceRef]:
        return [DeviceRef(b, b.generation) for b in self.bus.boards if b.present]

    def get_parent(self, dev: DeviceRef) -> None:
        return None

    def get_device_descriptor(self, dev: DeviceRef) -> DeviceDescriptor:
        return dev.board.descriptor

    def get_configuration_descriptor(self, dev: DeviceRef, config: int) -> ConfigurationDescriptor:
        if config != 0:
            raise IndexError("one configuration")
        return CONFIGURATION

    def get_interface_descriptor(self, dev: DeviceRef, intf: int, alt: int,
                                 config: int) -> InterfaceDescriptor:
        if intf != 0 or alt != 0 or config != 0:
            raise IndexError("one interface, one alternate setting")
        return InterfaceDescriptor(len(self._endpoints(dev)))

    def get_endpoint_descriptor(self, dev: DeviceRef, ep: int, intf: int, alt: int,
                                config: int) -> EndpointDescriptor:
        endpoints = self._endpoints(dev)
        if intf != 0 or alt != 0 or config != 0 or not 0 <= ep < len(endpoints):
            raise IndexError("no such endpoint")
        return endpoints[ep]

    @staticmethod
    def _endpoints(dev: DeviceRef) -> tuple[EndpointDescriptor, ...]:
        return RUNNING_ENDPOINTS if dev.board.running else ()

    # -- handles, configuration, interfaces ---------------------------------------------------

    def open_device(self, dev: DeviceRef) -> DeviceRef:
        dev.live()
        return dev

    def close_device(self, handle: DeviceRef) -> None:
        return None

    def set_configuration(self, handle: DeviceRef, value: int) -> None:
        handle.live()

    def get_configuration(self, handle: DeviceRef) -> int:
        handle.live()
        return CONFIGURATION.bConfigurationValue

    def set_interface_altsetting(self, handle: DeviceRef, intf: int, alt: int) -> None:
        handle.live()

    def claim_interface(self, handle: DeviceRef, intf: int) -> None:
        if intf != INTERFACE:
            raise stall()
        handle.live()

    def release_interface(self, handle: DeviceRef, intf: int) -> None:
        handle.live()

    def is_kernel_driver_active(self, handle: DeviceRef, intf: int) -> bool:
        return False

    def detach_kernel_driver(self, handle: DeviceRef, intf: int) -> None:
        return None

    def attach_kernel_driver(self, handle: DeviceRef, intf: int) -> None:
        return None

    def reset_device(self, handle: DeviceRef) -> None:
        handle.live()

    # -- transfers ------------------------------------------------------------------------

    def ctrl_transfer(self, handle: DeviceRef, bmRequestType: int, bRequest: int, wValue: int,
                      wIndex: int, data: array.array, timeout: int) -> int:
        board = handle.live()
        if bmRequestType & _DIR_IN:
            raise stall()  # no IN control requests are emulated
        with board.lock:
            board.control_out(bmRequestType, bRequest, wValue, data.tobytes())
        return len(data)

    def bulk_write(self, handle: DeviceRef, ep: int, intf: int, data: array.array,
                   timeout: int) -> int:
        board = handle.live()
        with board.lock:
            board.bulk_write(ep, data.tobytes())
        return len(data)

    def bulk_read(self, handle: DeviceRef, ep: int, intf: int, buff: array.array,
                  timeout: int) -> int:
        board = handle.live()
        if board.firmware is None:
            raise stall()
        data = board.firmware.read(ep, len(buff), timeout / 1000)
        handle.live()  # a board unplugged during the transfer returns nothing
        memoryview(buff)[: len(data)] = data
        return len(data)

    def clear_halt(self, handle: DeviceRef, ep: int) -> None:
        board = handle.live()
        if board.firmware is not None:
            board.firmware.clear_halt(ep)
