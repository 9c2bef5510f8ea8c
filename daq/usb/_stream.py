"""Streaming: a reader thread per board on the input endpoint, a watcher on the message one.

pyusb offers synchronous transfers only, so "bulk reads in flight" are one large read at a time
(about 10 ms of data, a multiple of the 512-byte packet): libusb splits it into many packet
requests, which keeps the host controller busy the way the Windows driver's 16 queued reads do.
The reader converts whole frames to int16 blocks and puts them into a bounded queue; the
consumer (`InputStream.take`, called from `Board.read`) never waits longer than its timeout.
When the queue is full the reader waits, so the data backs up into the board's FIFO, and a FIFO
overflow comes back as a message: the watcher thread turns every overflow, underflow or
over-sample message into an error, which `take` raises with the board's name and the sample
index. Nothing is ever dropped silently: a lost transfer, an overrun, extra data or a torn frame
ends the stream with an error.
"""

from __future__ import annotations

import array
import queue
import threading
import time

import numpy as np

from daq import DaqError, OverrunError, TriggerTimeoutError, UnderrunError

from ._errors import ProtocolError, TransferTimeoutError, with_context
from ._ids import EP_MSG_IN, EP_STREAM_IN, STREAM_PACKET_BYTES
from ._protocol import AsyncMessage, MessageType
from ._transport import UsbTransport
from ._unpublished import decode_stream

POLL_S = 0.1
"""Transfer timeout while idle (before the trigger, or on the message endpoint): how quickly
the threads notice a stop request."""
QUEUE_BLOCKS = 256
"""Bound of the reader's queue, in blocks of about 10 ms (about 2.5 s of data)."""


class InputStream:
    """The input stream of one armed board: a reader thread and a bounded queue of frames."""

    def __init__(self, transport: UsbTransport, n_channels: int, total: int | None,
                 rate_hz: float) -> None:
        """`total` samples per channel for a finite scan (None: until stopped); `rate_hz` is
        the sample rate, which sizes the transfers (about 10 ms each) and the stall timeout."""
        self.transport = transport
        self.n_channels = n_channels
        self.total = total
        self.frame_bytes = 2 * n_channels
        per_10ms = rate_hz * self.frame_bytes / 100
        self.read_bytes = int(min(256 * 1024, max(1, np.ceil(per_10ms / STREAM_PACKET_BYTES)))
                              * STREAM_PACKET_BYTES)
        self.stall_s = max(1.0, 10 * self.read_bytes / (rate_hz * self.frame_bytes))
        self.samples_received = 0
        self._queue: queue.Queue[np.ndarray] = queue.Queue(QUEUE_BLOCKS)
        self._failure: DaqError | None = None
        self._stop = threading.Event()
        self._pending: list[np.ndarray] = []
        self._thread = threading.Thread(target=self._run, name=f"usb-reader {transport.name}",
                                        daemon=True)

    def start(self) -> None:
        self._thread.start()

    def fail(self, error: DaqError) -> None:
        """Record the first failure of the stream; `take` raises it."""
        if self._failure is None:
            self._failure = error

    @property
    def failure(self) -> DaqError | None:
        """The error that ended the stream, if any."""
        return self._failure

    def request_stop(self) -> None:
        """Tell the reader to finish its current transfer and end (before the stop commands)."""
        self._stop.set()

    def close(self) -> None:
        """Stop the reader thread and wait for it."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def take(self, n: int, timeout_s: float, first_index: int) -> np.ndarray:
        """The next `n` frames as int16 (n, n_channels), or raise the stream's error.

        `first_index` is the sample index of the first frame, for the error messages.
        """
        if n == 0:
            return np.zeros((0, self.n_channels), np.int16)
        deadline = time.monotonic() + timeout_s
        have = sum(len(b) for b in self._pending)
        while have < n:
            if self._failure is not None:
                raise self._failure
            try:
                block = self._queue.get(timeout=min(0.05, max(0.0, deadline - time.monotonic())))
            except queue.Empty:
                if time.monotonic() >= deadline:
                    raise self._timeout(timeout_s, first_index + have) from None
                continue
            self._pending.append(block)
            have += len(block)
        data = np.concatenate(self._pending) if len(self._pending) > 1 else self._pending[0]
        self._pending = [data[n:]] if len(data) > n else []
        return data[:n]

    def _timeout(self, timeout_s: float, index: int) -> TriggerTimeoutError:
        name = self.transport.name
        if self.samples_received == 0:
            return TriggerTimeoutError(
                f"{name} delivered no samples within {timeout_s:.1f} s of being armed: it saw "
                "no trigger or no sample clock; check the trigger and clock cables and that "
                "the master board started"
            )
        return TriggerTimeoutError(
            f"{name}: samples stopped arriving at sample index {index} (nothing for "
            f"{timeout_s:.1f} s): the sample clock stopped or the board hung; check the clock "
            "cable"
        )

    def _run(self) -> None:
        try:
            self._read_loop()
        except DaqError as e:
            self.fail(with_context(e, f"at input sample index {self.samples_received}"))

    def _read_loop(self) -> None:
        buffer = array.array("B", bytes(self.read_bytes))
        carry = b""
        while not self._stop.is_set():
            if self.total is not None:
                if self.samples_received >= self.total:
                    return
                left = (self.total - self.samples_received) * self.frame_bytes - len(carry)
                size = min(self.read_bytes, -(-left // STREAM_PACKET_BYTES) * STREAM_PACKET_BYTES)
                if size != len(buffer):
                    buffer = array.array("B", bytes(size))
            started = self.samples_received > 0 or carry
            try:
                n = self.transport.bulk_read_into(EP_STREAM_IN, buffer,
                                                  self.stall_s if started else POLL_S)
            except TransferTimeoutError:
                if started and not self._stop.is_set():
                    raise OverrunError(
                        f"{self.transport.name}: the input stream stopped for {self.stall_s:.1f}"
                        " s in mid-scan; a partial transfer may have been lost, so the data is "
                        "no longer contiguous: check the clock cable and the USB connection"
                    ) from None
                continue
            if n == 0:
                continue
            data = carry + memoryview(buffer)[:n].tobytes()
            whole = len(data) - len(data) % self.frame_bytes
            carry = data[whole:]
            frames = decode_stream(data[:whole], self.n_channels)
            if self.total is not None and self.samples_received + len(frames) > self.total:
                raise ProtocolError(
                    f"{self.transport.name} sent more than the {self.total} samples of the scan: "
                    "the stream format guess in daq/usb/_unpublished.py may be wrong"
                )
            if self.total is not None and self.samples_received + len(frames) == self.total \
                    and carry:
                raise ProtocolError(
                    f"{self.transport.name} ended the scan with {len(carry)} bytes of a torn "
                    "frame: the stream format guess in daq/usb/_unpublished.py may be wrong"
                )
            if len(frames):
                self._put(frames)
                self.samples_received += len(frames)

    def _put(self, frames: np.ndarray) -> None:
        while not self._stop.is_set():
            try:
                self._queue.put(frames, timeout=0.05)
                return
            except queue.Full:
                continue


class MessageWatcher:
    """A thread reading the asynchronous message endpoint for the whole life of an open board,
    failing the attached stream (the current scan's) on bad news; between scans, messages
    are ignored. One thread per board, so no two ever read the endpoint at once."""

    def __init__(self, transport: UsbTransport) -> None:
        self.transport = transport
        self.stream: InputStream | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"usb-msg {transport.name}",
                                        daemon=True)

    def start(self) -> None:
        self._thread.start()

    def attach(self, stream: InputStream | None) -> None:
        """Report the messages from now on to `stream` (None: to nobody)."""
        self.stream = stream

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.transport.bulk_read(EP_MSG_IN, STREAM_PACKET_BYTES, POLL_S)
            except TransferTimeoutError:
                continue
            except DaqError:
                return  # unplugged or stalled: the reader reports it with the sample index
            stream = self.stream
            if not data or stream is None:
                continue
            try:
                message = AsyncMessage.decode(data)
            except ProtocolError as e:
                stream.fail(ProtocolError(f"{self.transport.name}: {e}"))
                continue
            error = self._error_for(message, stream.samples_received)
            if error is not None:
                stream.fail(error)

    def _error_for(self, message: AsyncMessage, k: int) -> DaqError | None:
        name = self.transport.name
        if message.kind is MessageType.INPUT_FIFO_OVERFLOW:
            return OverrunError(
                f"{name}: its input FIFO overflowed after the host had received {k} samples; "
                f"the data from sample index {k} on is not contiguous. The host read too "
                "slowly: put fewer boards on one USB controller or lower the rate"
            )
        if message.kind is MessageType.ADC_OVER_SAMPLE:
            return OverrunError(
                f"{name}: the sample clock is faster than its converters (over-sample) near "
                f"sample index {k}; lower the rate or check the external clock"
            )
        if message.kind is MessageType.OUTPUT_FIFO_UNDERFLOW:
            return UnderrunError(
                f"{name}: its output FIFO ran empty while the waveform played (input sample "
                f"index {k}); shorten the output burst"
            )
        if message.kind is MessageType.DAC_OVER_SAMPLE:
            return UnderrunError(
                f"{name}: the output clock is faster than its DACs near sample index {k}"
            )
        return None  # counter, digital-input and output-done messages need no action here
