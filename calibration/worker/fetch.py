"""Fetching a job's files from the daemon's file endpoint in chunks, with a bounded window.

Credit-based flow control (zguide ch.7): at most `window` chunk requests are in flight, each
answered by exactly one reply, so neither side ever queues more than `window` chunks and no
high-water mark can drop one. Every wait is bounded by `timeout_s`; each file is verified as a
whole against the journal's checksum (cache.py) and fetched again once if it does not match.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import zmq

from acquisition.contracts.job_messages import (
    FETCH_WINDOW,
    FILE_REPLY,
    Chunk,
    Fetch,
    FetchError,
    Job,
    JobFile,
    encode,
)

from .cache import ChecksumMismatch, FileCache


class FetchFailed(Exception):
    """The daemon could not or did not serve a file; `retryable` if another try may work."""

    def __init__(self, message: str, retryable: bool) -> None:
        super().__init__(message)
        self.retryable = retryable


@dataclass
class _Transfer:
    file: JobFile
    fd: int
    left: int  # bytes still to receive
    tries: int = 1


CHUNK_BYTES = 1 << 20
"""Bytes asked for per `fetch` (the file server answers with at most this many)."""
def fetch_job_files(sock: zmq.Socket, job: Job, cache: FileCache, chunk_bytes: int = CHUNK_BYTES,
                    window: int = FETCH_WINDOW, timeout_s: float = 30.0) -> int:
    """Fetch every file of `job` the cache lacks, over the connected DEALER `sock`; returns the
    bytes fetched. Raises FetchFailed, or ChecksumMismatch if a file is wrong twice."""
    transfers: dict[str, _Transfer] = {}
    requests: deque[tuple[str, int, int]] = deque()

    def start(file: JobFile, tries: int = 1) -> None:
        fd = os.open(cache.partial(job, file.path), os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        transfers[file.path] = _Transfer(file, fd, file.bytes, tries)
        requests.extend((file.path, offset, min(chunk_bytes, file.bytes - offset))
                        for offset in range(0, file.bytes, chunk_bytes))
        if file.bytes == 0:
            finish(transfers[file.path])

    def finish(transfer: _Transfer) -> None:
        del transfers[transfer.file.path]
        os.close(transfer.fd)
        try:
            cache.commit(job, transfer.file)
        except ChecksumMismatch:
            if transfer.tries >= 2:
                raise
            start(transfer.file, transfer.tries + 1)  # a damaged transfer is not a damaged file

    fetched = 0
    in_flight = 0
    try:
        for file in cache.wanted(job):
            start(file)
        limit = 4 * (len(requests) + 1) + 16  # every request answered once, files maybe twice
        for _ in range(limit):
            if not transfers:
                return fetched
            while requests and in_flight < window:
                path, offset, length = requests.popleft()
                sock.send(encode(Fetch(job_id=job.job_id, path=path, offset=offset,
                                       length=length)))
                in_flight += 1
            if not sock.poll(round(timeout_s * 1000), zmq.POLLIN):
                raise FetchFailed(f"the daemon's file endpoint did not answer within "
                                  f"{timeout_s:g} s", retryable=True)
            header, *data = sock.recv_multipart()
            in_flight -= 1
            reply = FILE_REPLY.validate_json(header)
            if isinstance(reply, FetchError):
                raise FetchFailed(f"the daemon cannot serve {reply.path or 'a file'}: "
                                  f"{reply.reason}", retryable=False)
            fetched += _write(transfers, reply, data, finish)
        raise FetchFailed(f"fetching the files of {job.job_id} did not end after {limit} "
                          "replies", retryable=True)
    finally:
        for transfer in transfers.values():
            os.close(transfer.fd)


def _write(transfers: dict[str, _Transfer], reply: Chunk, data: list[bytes],
           finish: Callable[[_Transfer], None]) -> int:
    """Write one chunk where it belongs; finish its file when complete. Bytes written."""
    transfer = transfers.get(reply.path)
    if transfer is None or len(data) != 1:
        return 0  # a late chunk of a file already restarted or finished
    os.pwrite(transfer.fd, data[0], reply.offset)
    transfer.left -= len(data[0])
    if transfer.left <= 0:
        finish(transfer)
    return len(data[0])
