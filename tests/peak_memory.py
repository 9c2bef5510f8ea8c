"""The peak memory of one call, measured in a fresh Python process (the RSS growth that
/proc/<pid>/status reports), for tests that assert a ceiling on what hostile input may cost."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import zlib

_PROLOGUE = """
import sys
from pathlib import Path

def _kib(key):
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise SystemExit("no " + key)
"""
_MEASURE = """
Path("/proc/self/clear_refs").write_text("5")  # the peak (VmHWM) starts again from now
_before = _kib("VmRSS")
try:
{call}
finally:
    print(f"PEAK_GROWTH_KIB={{_kib('VmHWM') - _before}}", file=sys.stderr)
"""


def peak_growth(setup: str, call: str,
                timeout: float = 120) -> tuple[int, subprocess.CompletedProcess]:
    """Run `setup` (imports, data) then `call` in a new interpreter; return the growth of its
    resident memory's peak during `call`, bytes, and the finished process (its output)."""
    script = (_PROLOGUE + textwrap.dedent(setup)
              + _MEASURE.format(call=textwrap.indent(textwrap.dedent(call), "    ")))
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=timeout)
    lines = [line for line in done.stderr.splitlines() if line.startswith("PEAK_GROWTH_KIB=")]
    assert lines, done.stderr
    return int(lines[-1].split("=")[1]) * 1024, done


def blank_png(width: int, height: int) -> bytes:
    """A valid 8-bit grey PNG of one colour, made without holding its pixels: a few hundred
    kilobytes for 16000 x 16000 (256 MB decoded)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return (len(data).to_bytes(4, "big") + body
                + zlib.crc32(body).to_bytes(4, "big"))

    compressor = zlib.compressobj(9)
    row = bytes(width + 1)  # filter byte 0, then the row's pixels
    parts = [compressor.compress(row) for _ in range(height)]
    idat = b"".join(parts) + compressor.flush()
    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")
