"""USB descriptors of the emulated boards, as the objects a pyusb backend hands to pyusb.

Before the firmware download a board shows the FX2 boot ROM's face (vendor class, no bulk
endpoints, the loader id from its EEPROM); afterwards the running firmware's descriptor as
decoded from Data Translation's DT9836 image: USB 2.0, one configuration, interface 0 with the
six bulk endpoints of `daq.usb._ids`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from daq.usb._ids import (
    COMMAND_PACKET_BYTES,
    EP_CMD_IN,
    EP_CMD_OUT,
    EP_MSG_IN,
    EP_STREAM_IN,
    EP_STREAM_OUT,
    EP_UNUSED_OUT,
    STREAM_PACKET_BYTES,
    VENDOR_ID,
)

SPEED_HIGH = 3
"""pyusb's code for a high-speed (480 Mbit/s) device."""
_BULK = 0x02


@dataclass
class DeviceDescriptor:
    idProduct: int
    address: int
    port_number: int
    bus: int = 1
    bLength: int = 18
    bDescriptorType: int = 1
    bcdUSB: int = 0x0200
    bDeviceClass: int = 0
    bDeviceSubClass: int = 0
    bDeviceProtocol: int = 0
    bMaxPacketSize0: int = 64
    idVendor: int = VENDOR_ID
    bcdDevice: int = 0x0001
    iManufacturer: int = 0
    iProduct: int = 0
    iSerialNumber: int = 0
    bNumConfigurations: int = 1
    speed: int = SPEED_HIGH

    @property
    def port_numbers(self) -> tuple[int, ...]:
        return (self.port_number,)


@dataclass(frozen=True)
class ConfigurationDescriptor:
    bLength: int = 9
    bDescriptorType: int = 2
    wTotalLength: int = 0
    bNumInterfaces: int = 1
    bConfigurationValue: int = 1
    iConfiguration: int = 0
    bmAttributes: int = 0x60
    bMaxPower: int = 0x32
    extra_descriptors: list[int] = field(default_factory=list)


@dataclass(frozen=True)
class InterfaceDescriptor:
    bNumEndpoints: int
    bLength: int = 9
    bDescriptorType: int = 4
    bInterfaceNumber: int = 0
    bAlternateSetting: int = 0
    bInterfaceClass: int = 0xFF
    bInterfaceSubClass: int = 0
    bInterfaceProtocol: int = 0
    iInterface: int = 0
    extra_descriptors: list[int] = field(default_factory=list)


@dataclass(frozen=True)
class EndpointDescriptor:
    bEndpointAddress: int
    wMaxPacketSize: int
    bLength: int = 7
    bDescriptorType: int = 5
    bmAttributes: int = _BULK
    bInterval: int = 0
    bRefresh: int = 0
    bSynchAddress: int = 0
    extra_descriptors: list[int] = field(default_factory=list)


RUNNING_ENDPOINTS: tuple[EndpointDescriptor, ...] = (
    EndpointDescriptor(EP_MSG_IN, STREAM_PACKET_BYTES),
    EndpointDescriptor(EP_CMD_OUT, COMMAND_PACKET_BYTES),
    EndpointDescriptor(EP_CMD_IN, COMMAND_PACKET_BYTES),
    EndpointDescriptor(EP_STREAM_OUT, STREAM_PACKET_BYTES),
    EndpointDescriptor(EP_STREAM_IN, STREAM_PACKET_BYTES),
    EndpointDescriptor(EP_UNUSED_OUT, STREAM_PACKET_BYTES),
)
"""The running firmware's endpoints, in descriptor order."""

CONFIGURATION = ConfigurationDescriptor()
"""Both faces have one configuration (value 1) with one interface."""


def device_descriptor_bytes(product_id: int) -> bytes:
    """The 18-byte device descriptor a firmware image carries (what the FX2 enumerates with)."""
    return bytes([18, 1, 0x00, 0x02, 0, 0, 0, 64, VENDOR_ID & 0xFF, VENDOR_ID >> 8,
                  product_id & 0xFF, product_id >> 8, 0x01, 0x00, 1, 2, 0, 1])


def find_device_descriptor(memory: bytes) -> int | None:
    """The product id of the first Data Translation device descriptor in `memory`, if any."""
    needle = bytes([18, 1])
    start = memory.find(needle)
    while start != -1:
        d = memory[start: start + 18]
        if len(d) == 18 and d[8] | d[9] << 8 == VENDOR_ID:
            return d[10] | d[11] << 8
        start = memory.find(needle, start + 1)
    return None
