"""The errors an emulated device raises, exactly as pyusb's libusb1 backend raises them."""

from __future__ import annotations

import errno

import usb.core


def stall() -> usb.core.USBError:
    """The endpoint answered with STALL (LIBUSB_ERROR_PIPE)."""
    return usb.core.USBError("Pipe error", -9, errno.EPIPE)


def timeout() -> usb.core.USBTimeoutError:
    """Nothing came within the timeout (LIBUSB_ERROR_TIMEOUT)."""
    return usb.core.USBTimeoutError("Operation timed out", -7, errno.ETIMEDOUT)


def no_device() -> usb.core.USBError:
    """The device left the bus (LIBUSB_ERROR_NO_DEVICE)."""
    return usb.core.USBError("No such device (it may have been disconnected)", -4, errno.ENODEV)
