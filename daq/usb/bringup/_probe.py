"""A read-only look at every Data Translation board on the bus, for a bring-up report.

What it reads, and nothing else: each board's USB descriptors as the host holds them (device,
configuration, interface and endpoints; the string descriptors with GET_DESCRIPTOR), and, on a
board whose firmware runs, the VERSION_ID register (R_SINGLE_WORD_LB) and the 16 bytes of its
EEPROM (R_MULTI_BYTE_I2C_REG). Commands go through `ReadOnlyChannel`, which refuses anything
but these reads before it reaches the wire: the probe never writes a register, never starts a
scan and never downloads firmware (a board in loader state is described from its descriptors
only). Its transfers go to a `TransferTrace` to attach to a bug report.

The report also says what the findings mean for the guesses of `_unpublished`: a Data
Translation product id no family knows, with the DT9836's endpoint table, is probably the
DT9816's running id (DT9816_RUNNING_PID); a version register value no family knows names an
unknown variant (DT9816_VERSION_IDS, or daq/_models.py for a DT9836).
"""

from __future__ import annotations

import time
from typing import Any

import usb.core
import usb.util
from pydantic import BaseModel, ConfigDict

from daq import DaqError

from .._channel import CommandChannel
from .._families import FAMILIES, DT9816, family_of
from .._ids import (
    EP_CMD_IN,
    EP_CMD_OUT,
    EP_MSG_IN,
    EP_STREAM_IN,
    EP_STREAM_OUT,
    EP_UNUSED_OUT,
    VENDOR_ID,
)
from .._protocol import Command, ReadI2cBytes, ReadWord, ReadWords
from .._registers import EEPROM_I2C_ADDRESS, EEPROM_SERIAL, Reg
from .._trace import TransferTrace
from .._transport import UsbTransport, usb_location
from ._errors import WriteRefusedError
from ._names import VARIANTS

READ_COMMANDS = (ReadWord, ReadWords, ReadI2cBytes)
"""The only commands the probe sends: they read registers and the EEPROM."""
EEPROM_BYTES = 16
RUNNING_ENDPOINTS = frozenset({EP_MSG_IN, EP_CMD_OUT, EP_CMD_IN, EP_STREAM_OUT, EP_STREAM_IN,
                               EP_UNUSED_OUT})
"""The endpoint table of the DT9836's running firmware (from its descriptor)."""
_SPEEDS = {1: "low", 2: "full", 3: "high", 4: "super", 5: "super+"}
_EEPROM_C0 = 0xC0
"""First EEPROM byte of an FX2 "C0 load": vendor, product and device ids follow (FX2 TRM)."""


class ReadOnlyChannel(CommandChannel):
    """A command channel that sends read commands only: any other command is refused before
    it reaches the wire (WriteRefusedError), so nothing the probe does changes a board."""

    def send(self, command: Command) -> tuple[int, ...]:
        if not isinstance(command, READ_COMMANDS):
            raise WriteRefusedError(
                f"{self.transport.name}: the probe sends read commands only, not "
                f"{command.code.name}"
            )
        return super().send(command)


class Endpoint(BaseModel):
    """One endpoint descriptor."""

    model_config = ConfigDict(frozen=True)

    address: int
    attributes: int
    max_packet: int


class ProbedBoard(BaseModel):
    """What the probe found on one device of vendor 0x0867.

    Attributes:
        usb_id: vendor:product; location: bus and port; bus, address: as a capture names it.
        speed: "high", "full", ... (None if the host does not say).
        family: "DT9836" / "DT9816" when the product id is known, else None.
        firmware_running: True for a running id, False for a loader id, None if unknown.
        descriptor: the device descriptor's fields; strings: manufacturer, product, serial
            strings (None where absent or unreadable).
        endpoints: interface 0's endpoints.
        version_id, model: the VERSION_ID register and the variant it names.
        eeprom: the EEPROM bytes 0..15 in hex; eeprom_ids: the loader ids it holds (C0 load);
            serial: its serial number (bytes 8..11, little-endian).
        findings: what the values mean for the driver's guesses, in words.
        error: why a step failed (busy, no permission, no reply), else None.
    """

    usb_id: str
    location: str
    bus: int | None
    address: int | None
    speed: str | None
    family: str | None
    firmware_running: bool | None
    descriptor: dict[str, int]
    strings: dict[str, str | None]
    endpoints: list[Endpoint]
    version_id: int | None = None
    model: str | None = None
    eeprom: str | None = None
    eeprom_ids: str | None = None
    serial: str | None = None
    findings: list[str] = []
    error: str | None = None


class ProbeReport(BaseModel):
    """Every board the probe found, and when (Unix time, s)."""

    time: float
    boards: list[ProbedBoard]

    def text(self) -> str:
        """The report in words, a paragraph per board."""
        if not self.boards:
            return "no device of Data Translation (vendor 0867) on the bus"
        out = []
        for b in self.boards:
            state = {True: "firmware running", False: "FX2 loader (no firmware)",
                     None: "unknown product id"}[b.firmware_running]
            lines = [f"{b.usb_id} at {b.location} (address {b.address}, {b.speed or '?'} "
                     f"speed): {b.family or '?'}, {state}"]
            eps = " ".join(f"0x{e.address:02x}/{e.max_packet}" for e in b.endpoints)
            lines.append(f"  endpoints {eps or 'none'}; strings {b.strings}")
            if b.version_id is not None:
                lines.append(f"  VERSION_ID 0x{b.version_id:04x}: {b.model or 'no known variant'}")
            if b.eeprom is not None:
                lines.append(f"  EEPROM {b.eeprom} (ids {b.eeprom_ids or '-'}, serial "
                             f"{b.serial})")
            lines += [f"  note: {f}" for f in b.findings]
            if b.error:
                lines.append(f"  error: {b.error}")
            out.append("\n".join(lines))
        return "\n".join(out)


def probe(backend: Any = None, trace: TransferTrace | None = None) -> ProbeReport:
    """Describe every device of vendor 0x0867 on the bus (None: the system's libusb)."""
    boards = [_probe_one(dev, trace)
              for dev in usb.core.find(find_all=True, backend=backend, idVendor=VENDOR_ID)]
    return ProbeReport(time=time.time(), boards=boards)


def _probe_one(dev: usb.core.Device, trace: TransferTrace | None) -> ProbedBoard:
    known = family_of(dev.idProduct)
    endpoints = _endpoints(dev)
    board = ProbedBoard(
        usb_id=f"{dev.idVendor:04x}:{dev.idProduct:04x}",
        location=usb_location(dev).split(" at ", 1)[1], bus=dev.bus, address=dev.address,
        speed=_SPEEDS.get(dev.speed) if dev.speed else None,
        family=known[0].name if known else None, firmware_running=known[1] if known else None,
        descriptor={k: int(getattr(dev, k)) for k in (
            "bcdUSB", "bcdDevice", "bDeviceClass", "bDeviceSubClass", "bDeviceProtocol",
            "bMaxPacketSize0", "bNumConfigurations", "iManufacturer", "iProduct",
            "iSerialNumber")},
        strings={k: _string(dev, getattr(dev, i)) for k, i in (
            ("manufacturer", "iManufacturer"), ("product", "iProduct"),
            ("serial", "iSerialNumber"))},
        endpoints=endpoints)
    runs = {e.address for e in endpoints} >= RUNNING_ENDPOINTS
    if known is None:
        board.findings.append(_unknown_id(dev.idProduct, runs))
    if (known is not None and known[1]) or (known is None and runs):
        _read_board(dev, trace, board)
    usb.util.dispose_resources(dev)
    return board


def _endpoints(dev: usb.core.Device) -> list[Endpoint]:
    try:
        for cfg in dev:
            for intf in cfg:
                if intf.bInterfaceNumber == 0 and intf.bAlternateSetting == 0:
                    return [Endpoint(address=e.bEndpointAddress, attributes=e.bmAttributes,
                                     max_packet=e.wMaxPacketSize) for e in intf]
    except (usb.core.USBError, NotImplementedError, IndexError):
        pass
    return []


def _string(dev: usb.core.Device, index: int) -> str | None:
    if not index:
        return None
    try:
        return str(usb.util.get_string(dev, index))
    except (usb.core.USBError, ValueError, NotImplementedError):
        return None


def _read_board(dev: usb.core.Device, trace: TransferTrace | None, board: ProbedBoard) -> None:
    """VERSION_ID and the EEPROM, through the read-only channel."""
    transport: UsbTransport | None = None
    try:
        transport = UsbTransport(dev, trace)
        channel = ReadOnlyChannel(transport)
        board.version_id = channel.read_registers([Reg.VERSION_ID])[0]
        board.model = VARIANTS.get(board.version_id)
        eeprom = bytes(channel.send(ReadI2cBytes(tuple(
            (EEPROM_I2C_ADDRESS, r) for r in range(EEPROM_BYTES)))))
    except DaqError as e:
        board.error = str(e)
        return
    finally:
        if transport is not None:
            transport.close()
    board.eeprom = eeprom.hex()
    board.serial = str(int.from_bytes(bytes(eeprom[r] for r in EEPROM_SERIAL), "little"))
    if eeprom[0] == _EEPROM_C0:
        vid, pid = (int.from_bytes(eeprom[i: i + 2], "little") for i in (1, 3))
        board.eeprom_ids = f"{vid:04x}:{pid:04x}"
    if board.model is None:
        family = board.family or DT9816.name
        where = ("DT9816_VERSION_IDS in daq/usb/_unpublished.py" if family == DT9816.name
                 else "the version ids in daq/_models.py")
        board.findings.append(f"VERSION_ID 0x{board.version_id:04x} names no known variant: "
                              f"add it to {where}")


def _unknown_id(product_id: int, runs: bool) -> str:
    known = ", ".join(f"{f.name} 0x{f.loader_pid:04x}/0x{f.running_pid:04x}" for f in FAMILIES)
    if runs:
        return (f"product id 0x{product_id:04x} is no known loader or running id ({known}) but "
                "has the DT9836's running endpoints: if this is a DT9816 with its firmware "
                f"running, set DT9816_RUNNING_PID = 0x{product_id:04x} in "
                "daq/usb/_unpublished.py (and in udev/60-micam-daq.rules)")
    return f"product id 0x{product_id:04x} is no known loader or running id ({known})"
