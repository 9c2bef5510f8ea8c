"""systemd integration without libsystemd: sd_notify datagrams, the watchdog, journald levels.

Under `Type=notify` systemd passes `$NOTIFY_SOCKET` (a path, or an abstract socket when it starts
with "@") and, with `WatchdogSec=`, `$WATCHDOG_USEC`. Outside systemd every call is a no-op, so
the daemon runs the same in a terminal. Tests use the same mechanism as a readiness handshake.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from typing import ClassVar


def sd_notify(*lines: str) -> bool:
    """Send `KEY=VALUE` lines to systemd; False when not started by systemd (or it is gone)."""
    address = os.environ.get("NOTIFY_SOCKET")
    if not address:
        return False
    if address.startswith("@"):
        address = "\0" + address[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
            sock.setblocking(False)  # never wait on a receiver that does not read
            sock.connect(address)
            sock.send("\n".join(lines).encode())
    except OSError:  # gone, or its queue full (BlockingIOError): the message is dropped
        return False
    return True


class Watchdog:
    """Pings `WATCHDOG=1` at half of `$WATCHDOG_USEC` (as sd_watchdog_enabled(3) advises).

    Call `tick` from the loop that services the hardware: if that loop wedges, the pings stop
    and systemd restarts the service.
    """

    def __init__(self) -> None:
        usec = os.environ.get("WATCHDOG_USEC", "")
        pid = os.environ.get("WATCHDOG_PID", "")
        enabled = usec.isdigit() and int(usec) > 0 and (not pid or pid == str(os.getpid()))
        self.interval_s: float | None = int(usec) / 2e6 if enabled else None
        self._last = 0.0

    def tick(self) -> None:
        if self.interval_s is None:
            return
        now = time.monotonic()
        if now - self._last >= self.interval_s:
            sd_notify("WATCHDOG=1")
            self._last = now


class JournaldFormatter(logging.Formatter):
    """Prefixes each line with its syslog priority (<3> error ... <7> debug), which journald
    reads from a service's stderr (SyslogLevelPrefix=yes is the default)."""

    _PRIORITY: ClassVar[dict[int, int]] = {
        logging.CRITICAL: 2, logging.ERROR: 3, logging.WARNING: 4, logging.INFO: 6,
        logging.DEBUG: 7}

    def format(self, record: logging.LogRecord) -> str:
        priority = self._PRIORITY.get(record.levelno, 6)
        return "\n".join(f"<{priority}>{line}" for line in super().format(record).splitlines())


def configure_logging(level: int = logging.INFO) -> None:
    """Log to stderr: with priority prefixes under journald ($JOURNAL_STREAM), with times else."""
    handler = logging.StreamHandler()
    if os.environ.get("JOURNAL_STREAM"):
        handler.setFormatter(JournaldFormatter("%(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)
