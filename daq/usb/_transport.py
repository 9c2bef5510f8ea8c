"""The transport layer: one pyusb device, its claimed interface, transfers with timeouts.

Everything USB-specific that is not the Data Translation protocol lives here: claiming the
interface (detaching a kernel driver such as comedi's if one is bound), control and bulk
transfers with timeouts in seconds, and turning pyusb's errors into driver errors that name the
board: ENODEV means unplugged (DeviceDisconnectedError), EPIPE a stalled endpoint, a timeout a
board that did not answer. Every transfer can be written to a `TransferTrace`.
"""

from __future__ import annotations

import array
import errno
from collections.abc import Callable
from typing import TypeVar

import usb.core
import usb.util

from daq import DeviceDisconnectedError

from ._errors import StalledEndpointError, TransferTimeoutError, UsbTransferError
from ._ids import INTERFACE
from ._trace import TransferTrace

T = TypeVar("T")

_LIBUSB_NO_DEVICE = -4
_LIBUSB_PIPE = -9
_CLEAR_FEATURE_TYPE = 0x02
"""bmRequestType of a standard request to an endpoint, host to device (USB 2.0, 9.3)."""
_CLEAR_FEATURE = 1
_ENDPOINT_HALT = 0


def usb_location(device: usb.core.Device) -> str:
    """Where a device sits, e.g. "0867:3698 at bus 1 port 2.1" (stable across re-enumeration)."""
    ports = ".".join(str(p) for p in (device.port_numbers or ())) or "?"
    return f"{device.idVendor:04x}:{device.idProduct:04x} at bus {device.bus} port {ports}"


class UsbTransport:
    """An opened board: transfers on its endpoints, errors that name it.

    `name` starts as the USB location and is replaced by "model serial ..." once the board
    model layer has identified the board, so that every later error names it properly.
    """

    def __init__(self, device: usb.core.Device, trace: TransferTrace | None = None,
                 claim: bool = True) -> None:
        self.device = device
        self.trace = trace
        self.name = usb_location(device)
        self._claimed = False
        if claim:
            self._guard("claim", lambda: self._claim())

    def _claim(self) -> None:
        try:
            if self.device.is_kernel_driver_active(INTERFACE):
                self.device.detach_kernel_driver(INTERFACE)
        except NotImplementedError:
            pass  # backends without kernel drivers (Windows, the emulated bus)
        usb.util.claim_interface(self.device, INTERFACE)
        self._claimed = True

    def control_out(self, request: int, value: int, index: int, data: bytes,
                    timeout_s: float, request_type: int) -> None:
        """A control transfer from host to device (used by the FX2 firmware loader)."""
        what = f"control request 0x{request:02x} (value 0x{value:04x})"
        self._guard(what, lambda: self._traced(
            lambda: self.device.ctrl_transfer(request_type, request, value, index, data,
                                              _ms(timeout_s)),
            "ctrl", data, request_type=request_type, request=request, value=value, index=index))

    def bulk_write(self, endpoint: int, data: bytes, timeout_s: float) -> None:
        """Write all of `data` to a bulk OUT endpoint."""
        def run() -> None:
            written = self._traced(lambda: self.device.write(endpoint, data, _ms(timeout_s)),
                                   "bulk", data, ep=endpoint)
            if written != len(data):
                raise UsbTransferError(
                    f"{self.name}: endpoint 0x{endpoint:02x} took {written} of {len(data)} "
                    "bytes; check the cable and the hub"
                )
        self._guard(f"write to endpoint 0x{endpoint:02x}", run)

    def bulk_read(self, endpoint: int, size: int, timeout_s: float) -> bytes:
        """Read up to `size` bytes from a bulk IN endpoint (fewer on a short packet)."""
        buffer = array.array("B", bytes(size))
        n = self.bulk_read_into(endpoint, buffer, timeout_s)
        return buffer[:n].tobytes()

    def bulk_read_into(self, endpoint: int, buffer: array.array, timeout_s: float) -> int:
        """Read into `buffer` (no allocation: the stream reader reuses one); return the count."""
        def run() -> int:
            n = 0
            status = "ok"
            try:
                n = self.device.read(endpoint, buffer, _ms(timeout_s))
                return n
            except usb.core.USBError as e:
                status = str(e)
                raise
            finally:
                self._trace("bulk", "in", memoryview(buffer)[:n] if n else None, status,
                            ep=endpoint)
        return self._guard(f"read from endpoint 0x{endpoint:02x}", run)

    def clear_halt(self, endpoint: int) -> None:
        """Clear a stall on `endpoint` (before a scan, and after a stalled transfer).

        Traced as what goes over the wire: the standard CLEAR_FEATURE(ENDPOINT_HALT) control
        request to the endpoint, as a usbmon capture shows it."""
        self._guard(f"clear halt on endpoint 0x{endpoint:02x}", lambda: self._traced(
            lambda: self.device.clear_halt(endpoint), "ctrl", None,
            request_type=_CLEAR_FEATURE_TYPE, request=_CLEAR_FEATURE, value=_ENDPOINT_HALT,
            index=endpoint))

    def close(self) -> None:
        """Release the interface and the handle; never raises (the board may be gone)."""
        try:
            if self._claimed:
                usb.util.release_interface(self.device, INTERFACE)
        except usb.core.USBError:
            pass
        finally:
            self._claimed = False
            usb.util.dispose_resources(self.device)

    def _traced(self, call: Callable[[], T], kind: str, data: bytes | None,
                **fields: int) -> T:
        """Run one OUT transfer (`call`, a pyusb call) and trace it, whatever its outcome."""
        status = "ok"
        try:
            return call()
        except usb.core.USBError as e:
            status = str(e)
            raise
        finally:
            self._trace(kind, "out", data, status, **fields)

    def _trace(self, kind: str, direction: str, data: bytes | memoryview | None, status: str,
               **fields: int) -> None:
        if self.trace is not None:
            self.trace.record(self.name, kind, direction,
                              None if data is None else bytes(data), status,
                              bus=self.device.bus, addr=self.device.address, **fields)

    def _guard(self, what: str, action: Callable[[], T]) -> T:
        """Run a pyusb call and translate its errors into driver errors naming the board."""
        try:
            return action()
        except usb.core.USBTimeoutError:
            raise TransferTimeoutError(f"{self.name}: {what} timed out") from None
        except usb.core.USBError as e:
            if e.errno == errno.ENODEV or e.backend_error_code == _LIBUSB_NO_DEVICE:
                raise DeviceDisconnectedError(
                    f"{self.name} is gone from the USB bus ({what} failed): check its cable "
                    "and power, then reconnect it"
                ) from None
            if e.errno == errno.EPIPE or e.backend_error_code == _LIBUSB_PIPE:
                raise StalledEndpointError(
                    f"{self.name} stalled the transfer ({what}); the board refused it"
                ) from None
            if e.errno in (errno.EACCES, errno.EPERM):
                raise UsbTransferError(
                    f"{self.name}: no permission for {what}; install the udev rules with "
                    "`sudo micam install udev` (udev/README.md) and replug the board"
                ) from None
            if e.errno == errno.EBUSY:
                raise UsbTransferError(
                    f"{self.name} is in use by another program ({what} failed); close it"
                ) from None
            raise UsbTransferError(f"{self.name}: {what} failed: {e}") from None


def _ms(timeout_s: float) -> int:
    """pyusb timeouts are whole milliseconds, and 0 would mean "wait forever": never send 0."""
    return max(1, round(timeout_s * 1000))
