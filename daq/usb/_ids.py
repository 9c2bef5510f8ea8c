"""USB identities and endpoints of the Data Translation boards (public facts).

Sources (see docs/usb-protocol.md): usb.ids for the vendor and the loader product ids; the
descriptor inside Data Translation's 2013 DT9836 Linux driver firmware for the DT9836 running
id 0x3698 and its endpoint table; the Cypress FX2 technical reference for the boot-loader
requests and the CPUCS register. The DT9816 running id is *not* public and lives with the other
guesses in `_unpublished`.
"""

from __future__ import annotations

VENDOR_ID = 0x0867
"""Data Translation, Inc."""

DT9836_LOADER_PID = 0x9836
"""DT9836 before its firmware is downloaded (the FX2 boot ROM answers)."""
DT9836_RUNNING_PID = 0x3698
"""DT9836 after the firmware download and re-enumeration."""
DT9816_LOADER_PID = 0x9816
"""DT9816 before its firmware is downloaded (usb.ids: "DT9816 ECON data acquisition module")."""

# Bulk endpoints of the running firmware (DT9836 driver, identical in uldaq for the DT9837).
EP_MSG_IN = 0x88
"""Asynchronous messages from the firmware (FIFO overflow, underflow, over-sample, ...)."""
EP_CMD_OUT = 0x01
"""64-byte command packets."""
EP_CMD_IN = 0x81
"""Replies to read commands."""
EP_STREAM_OUT = 0x06
"""The DAC output stream."""
EP_STREAM_IN = 0x82
"""The ADC input stream."""
EP_UNUSED_OUT = 0x04
"""Present in the descriptor, unused by every known driver."""

INTERFACE = 0
"""The one interface of the running firmware; it carries all six endpoints."""
STREAM_PACKET_BYTES = 512
"""High-speed max-packet size of the stream endpoints; bulk reads are sized in multiples."""
COMMAND_PACKET_BYTES = 64
"""Every command is one 64-byte packet; replies fit in one 64-byte packet."""

# Cypress FX2 boot loader (silicon: 0xA0; second-stage loader image: 0xA3).
FX2_REQUEST_INTERNAL = 0xA0
"""Vendor request writing internal RAM (and CPUCS); answered by the FX2 silicon itself."""
FX2_REQUEST_EXTERNAL = 0xA3
"""Vendor request writing external RAM; only answered while a loader image runs."""
FX2_CPUCS = 0xE600
"""CPU control register: 1 holds the 8051 in reset, 0 releases it."""
FX2_INTERNAL_RAM_END = 0x3FFF
"""Highest address written with 0xA0; everything above goes through the loader with 0xA3."""
VENDOR_OUT = 0x40
"""bmRequestType of a vendor request to the device, host to device."""
