"""The file-serving endpoint: byte ranges of a job's session files, for workers without the disk.

A worker may fetch only what its job names (the journaled files of the job's steps, and the
journal prefix), so a request can never read anything else of the machine: the names are safe
relative paths (the journal and the outbox are validated when read), and the file is opened
beneath the session directory without following a symbolic link anywhere on its way, and
sent only if it is a regular file with one name (acquisition.daemon.open_beneath).
Each request is answered with one chunk, read with `pread` from a file that is never rewritten
once journaled; the worker checks each whole file against the journal's SHA-256.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path

import zmq
from pydantic import ValidationError

from acquisition.contracts.job_messages import (
    FETCH,
    FETCH_WINDOW,
    Chunk,
    FetchError,
    encode,
    version_problem,
)
from acquisition.contracts.session import SessionError

from .open_beneath import check_sendable, open_beneath
from .outbox import JobRecord

log = logging.getLogger("micam.daemon")

MAX_FETCH_BYTES = 4096
"""The largest frame the files socket accepts: a `fetch` is a few hundred bytes of JSON."""
FETCH_QUEUE = 16
"""Fetches queued per worker connection (x MAX_FETCH_BYTES)."""
CHUNK_QUEUE = 2 * FETCH_WINDOW
"""Replies queued per worker connection. A worker keeps at most FETCH_WINDOW fetches in
flight, but ZeroMQ tells a queue's writer what its reader took only every half queue, so a
queue of exactly the window can seem full with fewer in it (and a refused reply stalls the
worker for its fetch timeout): twice the window never does. A peer that asks without reading
holds at most 16 chunks of 1 MiB in the daemon; the replies after are refused (`zmq.Again`,
logged)."""


class FileServer:
    """Answers `fetch` requests on a ROUTER socket; `find_job` looks a job up by id."""

    def __init__(self, sock: zmq.Socket, find_job: Callable[[str], JobRecord | None],
                 max_per_turn: int = 32) -> None:
        self.sock = sock
        sock.router_mandatory = 1  # a reply that cannot be queued is an error we can log
        self._find_job = find_job
        self._max_per_turn = max_per_turn

    def serve(self) -> None:
        """Answer the requests waiting (at most `max_per_turn`, so captures are not held up)."""
        for _ in range(self._max_per_turn):
            try:
                identity, *frames = self.sock.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            try:
                reply = self._answer(frames)
            except Exception as exc:  # a bug or an I/O error: answer, keep serving
                log.exception("file request failed")
                reply = [encode(FetchError(path="", reason=f"{type(exc).__name__}: {exc}"))]
            try:
                self.sock.send_multipart([identity, *reply], zmq.NOBLOCK)
            except zmq.ZMQError as exc:  # the worker went away, or does not read its chunks
                log.info("cannot answer a file request: %s", exc)

    def _answer(self, frames: list[bytes]) -> list[bytes]:
        if len(frames) != 1:
            return [encode(FetchError(path="", reason=f"a fetch is one frame; got {len(frames)}"))]
        problem = version_problem(frames[0])
        if problem is not None:
            return [encode(FetchError(path="", reason=problem))]
        try:
            fetch = FETCH.validate_json(frames[0])
        except ValidationError as exc:
            why = exc.errors()[0]["msg"]
            return [encode(FetchError(path="", reason=f"malformed fetch: {why}"))]
        job = self._find_job(fetch.job_id)
        size = job.allowed(fetch.path) if job is not None else None
        if job is None or size is None:
            return [encode(FetchError(path=fetch.path,
                                      reason=f"{fetch.path} is not a file of job {fetch.job_id}"))]
        if fetch.offset > size:
            return [encode(FetchError(path=fetch.path,
                                      reason=f"offset {fetch.offset} is past the end ({size})"))]
        length = min(fetch.length, size - fetch.offset)
        try:
            fd = open_beneath(Path(job.session_path), fetch.path)
        except SessionError as exc:
            return [encode(FetchError(path=fetch.path, reason=str(exc)))]
        try:
            check_sendable(fd, fetch.path)  # the journal grows past its prefix: any length
            data = os.pread(fd, length, fetch.offset)
        except SessionError as exc:
            return [encode(FetchError(path=fetch.path, reason=str(exc)))]
        finally:
            os.close(fd)
        return [encode(Chunk(path=fetch.path, offset=fetch.offset)), data]
