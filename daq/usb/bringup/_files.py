"""Capture files as a stream of records: pcap and pcapng through dpkt, every read bounded.

dpkt (a small, pure-Python packet library) reads both formats: classic pcap in either byte
order with micro- or nanosecond stamps, and pcapng's section, interface and packet blocks with
their timestamp resolution. It has no USB dissectors: `_usbmon` and `_usbpcap` decode the USB
headers. Around it this module adds:

- the file's format and byte order from its first bytes (the pcap magic number, or pcapng's
  byte-order magic at offset 8): the usbmon header is in the byte order of the file
  (tcpdump.org's link-type list, LINKTYPE_USB_LINUX), which dpkt does not expose;
- `_BoundedFile`, through which dpkt reads: a record length above MAX_RECORD_BYTES is a
  corrupt header (dpkt would allocate it), and a short read means a truncated file, so half a
  record is reported as such rather than decoded;
- records are yielded one at a time: a capture of many gigabytes is never held in memory.

dpkt's pcapng reader takes the link type of the first interface block for the whole section
(its issue #681): a capture of several interfaces must share one link type, as usbmon0 (every
bus at once) or several USBPcap interfaces do.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import dpkt

from ._errors import TraceError

MAX_RECORD_BYTES = 16 * 2**20
"""Largest record read: libpcap caps a USBPcap record at 1 MiB and the others at 256 KiB."""

LINKTYPE_USB_LINUX = 189
"""usbmon with the 48-byte header (`tcpdump -i usbmonN` on older libpcap)."""
LINKTYPE_USB_LINUX_MMAPPED = 220
"""usbmon with the 64-byte header (libpcap's memory-mapped usbmon reader; Wireshark)."""
LINKTYPE_USBPCAP = 249
"""Windows USBPcap (and Wireshark on Windows)."""
USB_LINKTYPES = (LINKTYPE_USB_LINUX, LINKTYPE_USB_LINUX_MMAPPED, LINKTYPE_USBPCAP)

_PCAP_BIG = (b"\xa1\xb2\xc3\xd4", b"\xa1\xb2\x3c\x4d", b"\xa1\xb2\xcd\x34")
_PCAP_LITTLE = tuple(m[::-1] for m in _PCAP_BIG)
_PCAPNG_SHB = b"\x0a\x0d\x0d\x0a"
_OTHER_LINKTYPES = {1: "Ethernet", 113: "Linux cooked", 276: "Linux cooked v2",
                    288: "raw USB 2.0 packets of a bus analyser", 186: "FreeBSD usbdump"}


@dataclass(frozen=True)
class Record:
    """One captured packet: its number in the file (from 0), time stamp (Unix s), bytes."""

    index: int
    ts: float
    data: bytes


def sniff(path: Path) -> str:
    """"pcap", "pcapng" or "micam" (a transfer trace) from the first bytes of `path`."""
    try:
        with path.open("rb") as f:
            head = f.read(12)
    except IsADirectoryError:
        raise TraceError(f"{path} is a directory; name a capture or trace file") from None
    except OSError as e:
        raise TraceError(f"cannot read {path}: {e.strerror or e}") from None
    if head[:4] in _PCAP_BIG + _PCAP_LITTLE:
        return "pcap"
    if head[:4] == _PCAPNG_SHB:
        return "pcapng"
    if head.lstrip()[:1] == b"{":
        return "micam"
    if not head:
        raise TraceError(f"{path} is empty")
    raise TraceError(
        f"{path} is neither a pcap or pcapng capture nor a micam transfer trace (it begins "
        f"with {head[:4].hex()}); capture with tcpdump or Wireshark on usbmon, or USBPcap"
    )


class _BoundedFile:
    """The file as dpkt reads it: each read bounded, short reads noticed, offset counted."""

    def __init__(self, f: BinaryIO, path: Path) -> None:
        self._f = f
        self._path = path
        self.offset = 0
        self.short = False
        """A read returned less than asked: the file ended there."""
        self.cut = False
        """The file ended inside a record (a short read that was not a clean end)."""

    def read(self, n: int = -1) -> bytes:
        if not 0 <= n <= MAX_RECORD_BYTES:
            raise TraceError(
                f"{self._path}: a record at byte {self.offset} claims {n} bytes, more than "
                f"the {MAX_RECORD_BYTES // 2**20} MiB a USB capture record holds: the file "
                "is corrupt"
            )
        data = self._f.read(n)
        if len(data) < n:
            self.cut = self.cut or bool(data) or self.short
            self.short = True
        self.offset += len(data)
        return data


@dataclass
class Capture:
    """An opened pcap or pcapng file: its link type, byte order and records."""

    path: Path
    linktype: int
    big_endian: bool
    _reader: object
    _file: _BoundedFile

    def records(self) -> Iterator[Record]:
        """The packets in file order; TraceError on a truncated or corrupt file."""
        packets = iter(self._reader)  # type: ignore[call-overload]
        index = 0
        while True:
            try:
                ts, data = next(packets)
            except StopIteration:
                break
            except (dpkt.Error, ValueError, struct.error) as e:  # dpkt's ways to say "corrupt"
                raise self._bad(index, e) from None
            if self._file.short:
                raise self._truncated(index)
            yield Record(index, float(ts), bytes(data))
            index += 1
        if self._file.cut:
            raise self._truncated(index)

    def _truncated(self, index: int) -> TraceError:
        return TraceError(
            f"{self.path} is truncated: it ends inside record {index} (byte {self._file.offset})"
            "; the capture was cut short (copy it again, or stop the capture cleanly)"
        )

    def _bad(self, index: int, error: Exception) -> TraceError:
        if self._file.short:
            return self._truncated(index)
        return TraceError(f"{self.path}: record {index} (near byte {self._file.offset}) is "
                          f"corrupt ({error or type(error).__name__}); the file is damaged")


def open_capture(path: Path, f: BinaryIO, kind: str) -> Capture:
    """Read the file header of `f` (a pcap or pcapng file opened by the caller, as `sniff`
    named it) and check that it holds USB traffic."""
    head = f.read(12)
    f.seek(0)
    big = head[:4] in _PCAP_BIG if kind == "pcap" else head[8:12] == b"\x1a\x2b\x3c\x4d"
    bounded = _BoundedFile(f, path)
    try:
        reader = dpkt.pcap.Reader(bounded) if kind == "pcap" else dpkt.pcapng.Reader(bounded)
    except (dpkt.Error, ValueError, struct.error) as e:  # dpkt's ways to say "corrupt"
        if bounded.short:
            raise TraceError(f"{path} is truncated: it ends inside its file header") from None
        raise TraceError(f"{path}: its {kind} file header is corrupt ({e}); the file is "
                         "damaged") from None
    linktype = int(reader.datalink()) & 0xFFFF  # the upper bits may carry FCS information
    if linktype not in USB_LINKTYPES:
        what = _OTHER_LINKTYPES.get(linktype, "not USB")
        raise TraceError(
            f"{path} is a capture of link type {linktype} ({what}), not of USB: capture on a "
            "usbmon interface (link types 189 and 220) or with USBPcap (249)"
        )
    return Capture(path, linktype, big, reader, bounded)
