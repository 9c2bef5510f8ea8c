"""Any trace file as transfers: usbmon or USBPcap captures (pcap, pcapng), or micam's own."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from . import _jsonl, _usbmon, _usbpcap
from ._files import LINKTYPE_USBPCAP, open_capture, sniff
from ._transfer import Transfer


def read_transfers(path: Path) -> Iterator[Transfer]:
    """Every transfer of the file at `path`, streamed; TraceError if it cannot be read.

    The format is taken from the file's first bytes, not its name.
    """
    kind = sniff(path)
    with path.open("rb") as f:
        if kind == "micam":
            yield from _jsonl.transfers(path, f)
            return
        capture = open_capture(path, f, kind)
        if capture.linktype == LINKTYPE_USBPCAP:
            yield from _usbpcap.transfers(path, capture.records())
        else:
            yield from _usbmon.transfers(path, capture.records(), capture.linktype,
                                         capture.big_endian)
