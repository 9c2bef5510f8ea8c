"""Firmware images: read FX2 RAM images from files the user provides.

The images belong to Data Translation and are not shipped with micam: the user points the
driver at a directory holding `a3load` (the second-stage loader) and `dt9836` / `dt9816`. Two
formats are read: Intel HEX (`.hex`, `.ihx`), and the Linux `ihex2fw` binary (`.fw`, as
installed under /lib/firmware/datx/: records of big-endian u32 address, big-endian u16 length,
data, padded to 4 bytes, ended by a zero-length record).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

from ._errors import FirmwareError
from ._ids import FX2_INTERNAL_RAM_END

FIRMWARE_DIR_ENV = "MICAM_FIRMWARE_DIR"
"""Environment variable naming the firmware directory when none is given."""
SUFFIXES = (".hex", ".ihx", ".fw")


@dataclass(frozen=True)
class FirmwareImage:
    """An FX2 RAM image: (address, bytes) segments in file order, and where it came from."""

    source: Path
    segments: tuple[tuple[int, bytes], ...]

    def internal(self) -> list[tuple[int, bytes]]:
        """Segments in internal RAM (written with vendor request 0xA0)."""
        return [(a, d) for a, d in self.segments if a <= FX2_INTERNAL_RAM_END]

    def external(self) -> list[tuple[int, bytes]]:
        """Segments in external RAM (written with 0xA3 through the loader)."""
        return [(a, d) for a, d in self.segments if a > FX2_INTERNAL_RAM_END]


def firmware_dir(given: Path | None) -> Path:
    """The firmware directory: `given`, else $MICAM_FIRMWARE_DIR; FirmwareError if neither."""
    if given is not None:
        return Path(given)
    env = os.environ.get(FIRMWARE_DIR_ENV)
    if env:
        return Path(env)
    raise FirmwareError(
        "a board needs its firmware but no firmware directory was given: pass one (or set "
        f"{FIRMWARE_DIR_ENV}) holding a3load and dt9836/dt9816 images from Data Translation"
    )


def load_image(directory: Path, stem: str) -> FirmwareImage:
    """Read `<directory>/<stem>.hex|.ihx|.fw`; FirmwareError naming what was looked for."""
    for suffix in SUFFIXES:
        path = directory / f"{stem}{suffix}"
        if path.is_file():
            data = path.read_bytes()
            try:
                segments = _read_fw(data) if suffix == ".fw" else _read_ihex(data.decode("ascii"))
            except (ValueError, UnicodeDecodeError, struct.error) as e:
                raise FirmwareError(f"{path} is not a valid firmware image: {e}") from None
            if not segments:
                raise FirmwareError(f"{path} holds no data records")
            return FirmwareImage(path, tuple(_split_at_boundary(segments)))
    looked = ", ".join(f"{stem}{s}" for s in SUFFIXES)
    raise FirmwareError(f"no firmware image {stem!r} in {directory} (looked for {looked})")


def write_ihex(path: Path, segments: list[tuple[int, bytes]], record_bytes: int = 16) -> None:
    """Write segments as Intel HEX (used to make synthetic test images; 16-bit addresses)."""
    lines = []
    for address, data in segments:
        if address < 0 or address + len(data) > 0x10000:
            raise ValueError(f"segment at 0x{address:x} leaves the FX2's 64 KiB address space")
        for off in range(0, len(data), record_bytes):
            chunk = data[off: off + record_bytes]
            lines.append(_record(address + off, 0, chunk))
    lines.append(_record(0, 1, b""))
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def _record(address: int, kind: int, data: bytes) -> str:
    body = bytes([len(data), address >> 8 & 0xFF, address & 0xFF, kind]) + data
    checksum = -sum(body) & 0xFF
    return ":" + (body + bytes([checksum])).hex().upper()


def _read_ihex(text: str) -> list[tuple[int, bytes]]:
    segments: list[tuple[int, bytes]] = []
    base = 0
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        if not line.startswith(":"):
            raise ValueError(f"line {number} does not start with ':'")
        raw = bytes.fromhex(line[1:])
        if len(raw) < 5 or len(raw) != raw[0] + 5:
            raise ValueError(f"line {number} has a wrong length")
        if sum(raw) & 0xFF:
            raise ValueError(f"line {number} has a wrong checksum")
        count, address, kind, data = raw[0], raw[1] << 8 | raw[2], raw[3], raw[4: 4 + raw[0]]
        if kind == 0:
            segments.append((base + address, data))
        elif kind == 1:
            return segments
        elif kind == 2:
            base = (data[0] << 8 | data[1]) << 4
        elif kind == 4:
            base = (data[0] << 8 | data[1]) << 16
        elif kind not in (3, 5):  # start addresses mean nothing to the FX2
            raise ValueError(f"line {number} has unknown record type {kind} ({count} bytes)")
    raise ValueError("no end-of-file record")


def _read_fw(data: bytes) -> list[tuple[int, bytes]]:
    segments: list[tuple[int, bytes]] = []
    offset = 0
    while True:
        address, length = struct.unpack_from(">IH", data, offset)
        if length == 0:
            return segments
        segments.append((address, data[offset + 6: offset + 6 + length]))
        offset += (6 + length + 3) & ~3


def _split_at_boundary(segments: list[tuple[int, bytes]]) -> list[tuple[int, bytes]]:
    """Split any segment that straddles the internal/external RAM boundary."""
    out = []
    for address, data in segments:
        cut = FX2_INTERNAL_RAM_END + 1 - address
        if 0 < cut < len(data):
            out += [(address, data[:cut]), (FX2_INTERNAL_RAM_END + 1, data[cut:])]
        else:
            out.append((address, data))
    return out
