"""HTTP/1.1 spoken by hand to a running `micam web`: any head, any body, sent as fast or as
slowly as a test wants, and the peak memory of the page's process."""

from __future__ import annotations

import json
import select
import socket
import time
from dataclasses import dataclass
from pathlib import Path

READ_S = 10.0


@dataclass
class Reply:
    status: int | None
    head: bytes
    body: bytes

    def error(self) -> str:
        return str(json.loads(self.body)["error"])


def parse_reply(data: bytes) -> Reply:
    """The first response in `data` (status None if there is none)."""
    head, _, body = data.partition(b"\r\n\r\n")
    parts = head.split(b" ", 2)
    status = int(parts[1]) if head.startswith(b"HTTP/") and len(parts) > 1 else None
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            body = body[:int(value)]
    return Reply(status, head, body)


def read_all(sock: socket.socket, timeout_s: float = READ_S) -> bytes:
    """Everything the server sends until it closes or nothing more comes for a moment after a
    whole response (or `timeout_s` passes)."""
    data = b""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([sock], [], [], 0.05 if _whole(data) else 0.2)
        if not ready:
            if _whole(data):
                break
            continue
        try:
            piece = sock.recv(65536)
        except ConnectionResetError:
            break
        if not piece:
            break
        data += piece
    return data


def _whole(data: bytes) -> bool:
    reply = parse_reply(data)
    if reply.status is None or b"\r\n\r\n" not in data:
        return False
    for line in reply.head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return len(data.partition(b"\r\n\r\n")[2]) >= int(value)
    return False


def exchange(port: int, request: bytes, timeout_s: float = READ_S) -> Reply:
    """Send `request` as it is, read the answer."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout_s) as sock:
        sock.sendall(request)
        return parse_reply(read_all(sock, timeout_s))


def head(method: str, path: str, host: str, *headers: str) -> bytes:
    lines = [f"{method} {path} HTTP/1.1", f"Host: {host}", *headers, "", ""]
    return "\r\n".join(lines).encode("latin-1")


def send_big_body(port: int, total: int, chunked: bool, piece: int = 2**20) -> Reply:
    """POST a command body of `total` bytes (announced in Content-Length, or chunked), all of
    it however early the page answers, then read the answer."""
    framing = "Transfer-Encoding: chunked" if chunked else f"Content-Length: {total}"
    data = b" " * piece
    with socket.create_connection(("127.0.0.1", port), timeout=READ_S) as sock:
        sock.sendall(head("POST", "/api/command", f"127.0.0.1:{port}",
                          "Content-Type: application/json", framing))
        try:
            for _ in range(total // piece):
                sock.sendall(b"%x\r\n%s\r\n" % (piece, data) if chunked else data)
            if chunked:
                sock.sendall(b"0\r\n\r\n")
        except (BrokenPipeError, ConnectionResetError):
            pass  # the page closed early: its answer may still be there to read
        return parse_reply(read_all(sock))


def _status_bytes(pid: int, field: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no {field} for process {pid}")


def reset_peak_rss(pid: int) -> int:
    """Start measuring the peak resident memory of process `pid` afresh (`5` into
    /proc/PID/clear_refs sets VmHWM to VmRSS); its resident memory now, bytes."""
    Path(f"/proc/{pid}/clear_refs").write_text("5")
    return _status_bytes(pid, "VmRSS")


def peak_rss(pid: int) -> int:
    """The peak resident memory of process `pid` since reset_peak_rss (VmHWM), bytes."""
    return _status_bytes(pid, "VmHWM")
