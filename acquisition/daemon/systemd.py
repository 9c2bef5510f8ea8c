"""systemd integration without libsystemd: sd_notify datagrams, the watchdog, the journal.

Under `Type=notify` systemd passes `$NOTIFY_SOCKET` (a path, or an abstract socket when it starts
with "@") and, with `WatchdogSec=`, `$WATCHDOG_USEC`. Outside systemd every call is a no-op, so
the daemon runs the same in a terminal. Tests use the same mechanism as a readiness handshake.

Under systemd (`$JOURNAL_STREAM` set) log records go to the journal by its native protocol, with
structured fields: `MICAM_SESSION_ID` and `MICAM_STEP` (from the record's `extra`, else from the
context `set_log_context` sets), so `journalctl MICAM_SESSION_ID=...` shows one session's log.
"""

from __future__ import annotations

import logging
import os
import socket
import struct
import sys
import time
from collections.abc import Mapping
from contextvars import ContextVar
from typing import ClassVar

JOURNAL_SOCKET = "/run/systemd/journal/socket"
"""journald's native socket; `$MICAM_JOURNAL_SOCKET` names another (tests)."""

LOG_FIELDS = ("session_id", "step")
"""The structured fields of micam's log records: pass them as `extra`, or set a context."""

_log_context: ContextVar[Mapping[str, str]] = ContextVar("micam_log_context", default={})


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


def set_log_context(session_id: str | None = None, step: str | None = None) -> None:
    """The session and step that this thread's next log records are about (None: none)."""
    fields = {"session_id": session_id, "step": step}
    _log_context.set({k: v for k, v in fields.items() if v is not None})


class ContextFilter(logging.Filter):
    """Gives every record `session_id` and `step` (its `extra`, else the context, else None)
    and `context`, the text " [session S, step P]" for the plain formats ("" without)."""

    def filter(self, record: logging.LogRecord) -> bool:
        context = _log_context.get()
        for key in LOG_FIELDS:
            if getattr(record, key, None) is None:
                setattr(record, key, context.get(key))
        parts = [f"{name} {value}" for name, value in
                 (("session", getattr(record, "session_id", None)),
                  ("step", getattr(record, "step", None))) if value]
        record.context = f" [{', '.join(parts)}]" if parts else ""
        return True


def _journal_field(key: str, value: str) -> bytes:
    """One field of the native journal protocol (a value with a newline: length-prefixed)."""
    data = value.encode("utf-8", "replace")
    if b"\n" in data:
        return key.encode() + b"\n" + struct.pack("<Q", len(data)) + data + b"\n"
    return key.encode() + b"=" + data + b"\n"


class JournaldHandler(logging.Handler):
    """Sends each record to journald as one datagram: MESSAGE, PRIORITY, SYSLOG_IDENTIFIER,
    the logger and code location, and MICAM_SESSION_ID / MICAM_STEP when known. A record the
    journal does not take (gone, full) goes to stderr with its priority prefix instead."""

    def __init__(self, path: str, identifier: str) -> None:
        super().__init__()
        self.path, self.identifier = path, identifier
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        self._fallback = JournaldFormatter("%(name)s: %(message)s%(context)s")

    def emit(self, record: logging.LogRecord) -> None:
        fields = {
            "MESSAGE": self.format(record),
            "PRIORITY": str(JournaldFormatter._PRIORITY.get(record.levelno, 6)),
            "SYSLOG_IDENTIFIER": self.identifier,
            "MICAM_LOGGER": record.name,
            "CODE_FILE": record.pathname, "CODE_LINE": str(record.lineno),
            "CODE_FUNC": record.funcName,
        }
        for key in LOG_FIELDS:
            value = getattr(record, key, None)
            if value is not None:
                fields[f"MICAM_{key.upper()}"] = str(value)
        try:
            self._sock.sendto(b"".join(_journal_field(k, v) for k, v in fields.items()),
                              self.path)
        except OSError:
            print(self._fallback.format(record), file=sys.stderr, flush=True)

    def close(self) -> None:
        self._sock.close()
        super().close()


class StderrHandler(logging.StreamHandler):
    """Writes to whatever sys.stderr is when a record comes, not the one at set-up time (a
    stream replaced since, as a test's captured one, may be closed by then)."""

    @property  # type: ignore[override]
    def stream(self) -> object:
        return sys.stderr

    @stream.setter
    def stream(self, _value: object) -> None:
        pass


def configure_logging(level: int = logging.INFO, identifier: str = "micam") -> None:
    """Log from `level` up: to the journal with structured fields under systemd
    ($JOURNAL_STREAM and its socket), else to stderr with times and the session and step."""
    journal = os.environ.get("MICAM_JOURNAL_SOCKET", JOURNAL_SOCKET)
    handler: logging.Handler
    if os.environ.get("JOURNAL_STREAM") and os.path.exists(journal):
        handler = JournaldHandler(journal, identifier)
        handler.setFormatter(logging.Formatter("%(name)s: %(message)s"))
    else:
        handler = StderrHandler()
        handler.setFormatter(logging.Formatter(
            "%(asctime)s %(levelname)s %(name)s: %(message)s%(context)s"))
    handler.addFilter(ContextFilter())
    root = logging.getLogger()
    for old in root.handlers:
        if isinstance(old, JournaldHandler):  # its socket is ours; other handlers are not
            old.close()
    root.handlers[:] = [handler]
    root.setLevel(level)
