"""The USB driver for Data Translation DT9836 and DT9816 boards (pyusb).

Layers, each in its own module and swappable:

- transport (`_transport`): one pyusb device, its interface, transfers with timeouts, errors
  naming the board, an optional transfer trace (`_trace`);
- wire protocol (`_ids`, `_protocol`, `_registers`, `_channel`): USB ids and endpoints, the
  64-byte command packets with byte order per command, the FPGA register map; the FX2 firmware
  loader (`_fx2`, images from a user-given directory via `_images`);
- board models (`_families`, `_board`, `_stream`): the DT9836 / DT9816 variant tables, the
  `daq.Board` implementation, the reader and message-watcher threads;
- `_unpublished`: every guess about what is not public (the DT9836 stream format and start
  sequence, all of the DT9816), in one place, to be corrected against a trace.

Typical use: `boards = open_boards(["12345", "12346"], firmware_dir=...)`, then a
`daq.SyncGroup(boards)`. Tests and `micam simulate --backend usb-emulated` pass the emulated
bus of `sim.usb` as `backend`.
"""

from daq import ChannelLevel, SelftestReport, selftest

from ._board import UsbBoard, identify
from ._discovery import BoardInfo, download_firmware, find_devices, list_boards, open_boards
from ._errors import (
    FirmwareError,
    ProtocolError,
    StalledEndpointError,
    TransferTimeoutError,
    UsbTransferError,
)
from ._families import DT9816, DT9836, FAMILIES, Family
from ._images import FIRMWARE_DIR_ENV, FirmwareImage, load_image, write_ihex
from ._trace import TransferTrace
from ._transport import UsbTransport

__all__ = [
    "DT9816",
    "DT9836",
    "FAMILIES",
    "FIRMWARE_DIR_ENV",
    "BoardInfo",
    "ChannelLevel",
    "Family",
    "FirmwareError",
    "FirmwareImage",
    "ProtocolError",
    "SelftestReport",
    "StalledEndpointError",
    "TransferTimeoutError",
    "TransferTrace",
    "UsbBoard",
    "UsbTransferError",
    "UsbTransport",
    "download_firmware",
    "find_devices",
    "identify",
    "list_boards",
    "load_image",
    "open_boards",
    "selftest",
    "write_ihex",
]
