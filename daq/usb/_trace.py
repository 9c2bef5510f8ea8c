"""The transfer trace: every USB transfer written to a file, one JSON object per line.

Why: the DT9836 stream format and start sequence and all of the DT9816 protocol are guesses
(see `_unpublished`). A lab with the hardware runs the driver with a trace and compares it with
a usbmon / USBPcap capture of Data Translation's own software; the differences say what to
correct (`micam daq trace diff`, `daq.usb.bringup`, reads these files and the captures). Each
line holds: `t` (seconds since the trace was opened, monotonic clock), `wall` (Unix time,
seconds), `dev` (the board's name), `bus` and `addr` (its USB bus number and device address, as
a capture names it), `kind` ("ctrl" or "bulk"), `dir` ("out"/"in"), `ep` (endpoint address) or
the control setup fields (`request_type`, `request`, `value`, `index`), `len` (bytes
transferred), `status` ("ok" or the error) and `data` (hex, cut to `max_data_bytes` so a
14 MB/s stream stays traceable).
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any, TextIO


class TransferTrace:
    """A thread-safe JSON-lines log of USB transfers; use as a context manager or close()."""

    def __init__(self, path: Path | str, max_data_bytes: int = 64) -> None:
        self.path = Path(path)
        self.max_data_bytes = max_data_bytes
        self._file: TextIO = self.path.open("w", encoding="utf-8")
        self._lock = threading.Lock()
        self._t0 = time.monotonic()

    def record(self, dev: str, kind: str, direction: str, data: bytes | None, status: str,
               **fields: Any) -> None:
        """Write one transfer; `data` is what went over the wire (None if nothing did)."""
        entry: dict[str, Any] = {
            "t": round(time.monotonic() - self._t0, 6),
            "wall": round(time.time(), 6),
            "dev": dev,
            "kind": kind,
            "dir": direction,
            **fields,
            "len": 0 if data is None else len(data),
            "status": status,
        }
        if data:
            entry["data"] = bytes(data[: self.max_data_bytes]).hex()
        line = json.dumps(entry)
        with self._lock:
            self._file.write(line + "\n")

    def close(self) -> None:
        with self._lock:
            self._file.close()

    def __enter__(self) -> TransferTrace:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
