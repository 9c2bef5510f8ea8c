"""Finding and opening boards: enumerate, download firmware where needed, identify.

`list_boards` reports what is plugged in (the CLI's `micam daq list`); `open_boards` returns
ready driver boards, downloading the firmware into boards that enumerate with their loader id
and waiting for them to come back with their running id. Both take a pyusb backend (None: the
system's libusb), which is how the emulated bus of `sim.usb` plugs in.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import usb.core
from pydantic import BaseModel, ConfigDict

from daq import ConfigurationError, DaqError

from . import _fx2
from ._board import UsbBoard, identify
from ._channel import CommandChannel
from ._families import LOADER_IMAGE, Family, family_of
from ._ids import VENDOR_ID
from ._images import firmware_dir as resolve_firmware_dir
from ._images import load_image
from ._trace import TransferTrace
from ._transport import UsbTransport, usb_location

REENUMERATE_TIMEOUT_S = 10.0
"""How long a board may take to come back after its firmware download (uldaq waits 5 s)."""


class BoardInfo(BaseModel):
    """One board found on the bus.

    Attributes:
        family: "DT9836" or "DT9816".
        model: the variant, e.g. "DT9836-12-2"; None until the firmware runs.
        serial: the serial number from the board EEPROM; None until the firmware runs.
        firmware_loaded: whether the board enumerates with its running id.
        usb_id: vendor:product as lsusb shows it.
        location: bus and port, stable across re-enumeration.
        error: why the board could not be identified (busy, no permission, ...), else None.
    """

    model_config = ConfigDict(frozen=True)

    family: str
    model: str | None
    serial: str | None
    firmware_loaded: bool
    usb_id: str
    location: str
    error: str | None = None


def find_devices(backend: Any = None) -> list[tuple[usb.core.Device, Family, bool]]:
    """Every Data Translation board on the bus: (device, family, firmware running?)."""
    found = []
    for dev in usb.core.find(find_all=True, backend=backend, idVendor=VENDOR_ID):
        known = family_of(dev.idProduct)
        if known is not None:
            found.append((dev, *known))
    return found


def list_boards(backend: Any = None) -> list[BoardInfo]:
    """Describe every board on the bus, reading model and serial from those that run."""
    infos = []
    for dev, family, running in find_devices(backend):
        location = usb_location(dev).split(" at ", 1)[1]
        info: dict[str, object] = {
            "family": family.name, "model": None, "serial": None, "firmware_loaded": running,
            "usb_id": f"{dev.idVendor:04x}:{dev.idProduct:04x}", "location": location}
        if running:
            transport: UsbTransport | None = None
            try:
                transport = UsbTransport(dev)
                identity = identify(CommandChannel(transport), family)
                info.update(model=identity.model.name, serial=identity.serial)
            except DaqError as e:
                info.update(error=str(e))
            finally:
                if transport is not None:
                    transport.close()
        infos.append(BoardInfo.model_validate(info))
    return infos


def open_boards(serials: Sequence[str] | None = None, backend: Any = None,
                firmware_dir: Path | None = None, trace: TransferTrace | None = None,
                reenumerate_timeout_s: float = REENUMERATE_TIMEOUT_S) -> list[UsbBoard]:
    """Open boards ready for scanning, in the order of `serials` (None: every board found).

    Boards without firmware get it from `firmware_dir` (or $MICAM_FIRMWARE_DIR) first.
    """
    pending = [(dev, fam) for dev, fam, running in find_devices(backend) if not running]
    if pending:
        directory = resolve_firmware_dir(firmware_dir)
        for dev, family in pending:
            download_firmware(dev, family, directory, backend, trace, reenumerate_timeout_s)
    boards: list[UsbBoard] = []
    try:
        for dev, family, running in find_devices(backend):
            if running:
                boards.append(UsbBoard(UsbTransport(dev, trace), family))
        return _select(boards, serials)
    except BaseException:
        for board in boards:
            board.close()
        raise


def download_firmware(device: usb.core.Device, family: Family, directory: Path,
                      backend: Any = None, trace: TransferTrace | None = None,
                      timeout_s: float = REENUMERATE_TIMEOUT_S) -> usb.core.Device:
    """Download `family`'s firmware from `directory` into a board in loader state; return the
    device once it has re-enumerated with its running id."""
    loader = load_image(directory, LOADER_IMAGE)
    image = load_image(directory, family.firmware)
    bus, ports = device.bus, tuple(device.port_numbers or ())
    transport = UsbTransport(device, trace, claim=False)
    where = transport.name
    try:
        _fx2.download(transport, loader, image)
    finally:
        transport.close()

    def find(**kw: Any) -> Any:
        return usb.core.find(backend=backend, **kw)

    return _fx2.wait_for_running(find, bus, ports, family.running_pid, where, timeout_s)


def _select(boards: list[UsbBoard], serials: Sequence[str] | None) -> list[UsbBoard]:
    if serials is None:
        return boards
    by_serial = {b.identity.serial: b for b in boards}
    missing = [s for s in serials if s not in by_serial]
    if missing:
        found = ", ".join(str(b.identity) for b in boards) or "none"
        raise ConfigurationError(
            f"board serial(s) {', '.join(missing)} not found on the USB bus (found: {found}); "
            "check the cables and `micam daq list`"
        )
    chosen = [by_serial[s] for s in serials]
    for board in boards:
        if board not in chosen:
            board.close()
    return chosen
