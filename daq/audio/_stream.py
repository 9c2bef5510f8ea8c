"""One device's continuous PortAudio stream: inputs kept in a ring, outputs played on schedule.

The stream runs from the first `arm` until the board is closed or configured differently, so
that its output-to-input latency (the interface's buffers and converters: it is measured by
the reference microphone, never assumed) stays the same for every recording, and so that
several interfaces keep a fixed sample offset between them. Input and output run on one
callback (a full-duplex stream, one device clock): the callback that hands over input frames
f .. f + n - 1 also takes output frames f .. f + n - 1, so an output sample scheduled at frame
W and the input sample recorded at frame W are one sample clock edge apart, apart from the
device's fixed latency.

The callback does the least it can (PortAudio calls it on its own thread, often the audio
server's): it turns the input into 16-bit codes in a ring, copies the scheduled output,
counts frames and notes PortAudio's status flags. A flagged input overflow or output
underflow (an xrun: the host was late and samples were lost) is kept with its frame, so the
board can name the sample index at which its recording broke.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from daq import CODE_FULL_SCALE, ConfigurationError, DeviceDisconnectedError, OverrunError

from ._devices import AudioDeviceInfo
from ._jack_watch import JackWatch
from ._portaudio import abandon, portaudio, stream_closed, stream_opened

RING_S = 4.0
"""Seconds of input the ring keeps: a reader may trail the device by this much."""
FIRST_CALLBACK_S = 2.0
"""A stream that has not called back this long after its start is not running."""
WAIT_SLICE_S = 0.1
"""A waiting reader checks this often whether the stream is still alive."""
SETTLE_S = 1.0
"""No recording starts in a new stream's first second, nor before its `SETTLE_CALLBACKS`th
callback: a host API may flag xruns while it connects the stream (JACK reorders its graph; one
came 24 periods after the start, whatever the period), which must not break a recording."""
SETTLE_CALLBACKS = 32

# PortAudio's error codes (portaudio.h) for a refused configuration or a missing device.
_INVALID_CHANNELS = -9998
_INVALID_RATE = -9997
_INVALID_DEVICE = -9996
_DEVICE_UNAVAILABLE = -9985


@dataclass(frozen=True)
class Fault:
    """An xrun PortAudio flagged: which kinds, at the first frame of the callback after it.

    The flag comes with the callback after the one that was late, so a recording is whole
    only once the stream has called back past its last sample without a flag: its last read
    waits for one more callback (`DuplexStream.wait_frames`)."""

    kinds: tuple[str, ...]
    frame: int


def codes_of(samples: np.ndarray) -> np.ndarray:
    """Float samples (full scale +-1) as int16 codes, rounded and clipped."""
    scaled = np.rint(samples * CODE_FULL_SCALE)
    return np.clip(scaled, -CODE_FULL_SCALE, CODE_FULL_SCALE - 1).astype(np.int16)


def refused(device: AudioDeviceInfo, rate_hz: float, n_in: int, n_out: int,
            exc: Exception) -> Exception:
    """The driver-layer error for a stream PortAudio would not open."""
    code = exc.args[1] if len(exc.args) > 1 and isinstance(exc.args[1], int) else None
    asked = f"{n_in} inputs and {n_out} outputs at {rate_hz:.0f} S/s"
    if code == _INVALID_RATE:
        return ConfigurationError(
            f"{device} refuses the sample rate {rate_hz:.0f} S/s ({exc}); its default is "
            f"{device.default_rate_hz:.0f} S/s: set sample_rate_hz to a rate it offers (under "
            "JACK, the server's rate: jackd -r)")
    if code == _INVALID_CHANNELS:
        return ConfigurationError(
            f"{device} refuses {asked} ({exc}); it has {device.inputs} inputs and "
            f"{device.outputs} outputs")
    if code in (_INVALID_DEVICE, _DEVICE_UNAVAILABLE):
        return DeviceDisconnectedError(
            f"{device} cannot be opened ({exc}): it was unplugged, or another program holds "
            "it; close that program (or route it through the audio server) and try again")
    return ConfigurationError(f"{device} cannot open a stream of {asked}: {exc}")


class DuplexStream:
    """A running stream of `device` (module docstring).

    Args:
        device: the device.
        rate_hz: samples per second per channel.
        n_inputs, n_outputs: channels 0 .. n - 1 of the device are opened (no outputs: an
            input-only stream).
        block_frames: frames per callback, 0 for the host's choice.
        latency: PortAudio's suggested latency ("low", "high" or seconds).
        name: how errors name it (the board's identity; default the device).
    """

    def __init__(self, device: AudioDeviceInfo, rate_hz: float, n_inputs: int, n_outputs: int,
                 block_frames: int = 0, latency: str | float = "high",
                 name: str | None = None) -> None:
        sd = portaudio()
        self.device = device
        self.name = name or str(device)
        self.rate_hz = float(rate_hz)
        self.n_inputs, self.n_outputs = n_inputs, n_outputs
        self._ring = np.zeros((max(int(RING_S * rate_hz), 65_536), n_inputs), dtype=np.int16)
        self._cond = threading.Condition()
        self.frames = 0  # input frames delivered so far: the stream's sample clock
        self.anchor: tuple[int, float] | None = None  # (first frame of a callback, its time)
        self.max_block = 0
        self.faults: list[Fault] = []  # the latest ones
        self.fault_count = 0  # every one since the start
        self._playing: tuple[int, np.ndarray] | None = None  # (first frame, float32 samples)
        self._closed = False
        self.started_s = time.monotonic()
        kwargs: dict[str, Any] = dict(device=device.index, samplerate=rate_hz, dtype="float32",
                                      blocksize=block_frames, latency=latency,
                                      callback=self._callback)
        try:
            if n_outputs:
                self._stream = sd.Stream(channels=(n_inputs, n_outputs), **kwargs)
            else:
                self._stream = sd.InputStream(channels=n_inputs, callback=self._input_callback,
                                              **{k: v for k, v in kwargs.items()
                                                 if k != "callback"})
        except sd.PortAudioError as exc:
            raise refused(device, rate_hz, n_inputs, n_outputs, exc) from None
        stream_opened()
        self._watch = JackWatch(device.name) if "JACK" in device.host_api else None
        try:
            self._stream.start()
        except sd.PortAudioError as exc:
            self._release()
            raise refused(device, rate_hz, n_inputs, n_outputs, exc) from None

    # -- the callback (PortAudio's thread) ----------------------------------------------------

    def _input_callback(self, indata: np.ndarray, frames: int, time_info: Any,
                        status: Any) -> None:
        self._callback(indata, None, frames, time_info, status)

    def _callback(self, indata: np.ndarray, outdata: np.ndarray | None, frames: int,
                  time_info: Any, status: Any) -> None:
        now = time.monotonic()
        f0 = self.frames
        kinds = tuple(k for k, flagged in (("input overflow", status.input_overflow),
                                           ("output underflow", status.output_underflow))
                      if flagged)
        ring = self._ring
        i = f0 % ring.shape[0]
        first = min(frames, ring.shape[0] - i)
        codes = codes_of(indata)
        ring[i: i + first] = codes[:first]
        if first < frames:
            ring[: frames - first] = codes[first:]
        if outdata is not None:
            outdata.fill(0.0)
            playing = self._playing
            if playing is not None:
                start, wave = playing
                lo, hi = max(f0, start), min(f0 + frames, start + wave.shape[0])
                if lo < hi:
                    outdata[lo - f0: hi - f0] = wave[lo - start: hi - start]
        with self._cond:
            if kinds:
                self.faults = [*self.faults[-31:], Fault(kinds, f0)]
                self.fault_count += 1
            self.frames = f0 + frames
            self.anchor = (f0, now)
            self.max_block = max(self.max_block, frames)
            self._cond.notify_all()

    # -- what the board asks ------------------------------------------------------------------

    @property
    def alive(self) -> bool:
        """False once the stream stopped by itself (device or server gone), its JACK device
        left, or it was closed."""
        gone = self._watch is not None and self._watch.gone is not None
        return not self._closed and bool(self._stream.active) and not gone

    def first_window(self) -> int:
        """The earliest frame a recording may start at now: past the callback that may be
        running (it began at `frames` at the latest), so that an output scheduled now plays
        whole, and past the stream's settling."""
        settled = max(round(SETTLE_S * self.rate_hz), SETTLE_CALLBACKS * self.max_block)
        return max(self.frames + max(self.max_block, 1024) + 256, settled)

    def play(self, start_frame: int, samples: np.ndarray | None) -> None:
        """Play float32 `samples` (n, n_outputs) from stream frame `start_frame` (None: stop
        playing)."""
        with self._cond:
            self._playing = None if samples is None else (start_frame, samples)

    def wait_running(self, timeout_s: float = FIRST_CALLBACK_S) -> None:
        """Return once the stream has called back at least once."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self.anchor is None:
                self._check_alive()
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DeviceDisconnectedError(
                        f"{self.name} started but delivered no samples within {timeout_s:g} s; "
                        "is its audio server running (under JACK: jackd), is it in use?")
                self._cond.wait(min(left, WAIT_SLICE_S))

    def wait_frames(self, frame: int, timeout_s: float) -> int:
        """Wait until the stream has delivered `frame` frames (or timeout_s passed, or it
        died); the frames delivered then."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self.frames < frame and self._stream.active:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(min(left, WAIT_SLICE_S))
            return self.frames

    def take(self, first: int, n: int, timeout_s: float) -> np.ndarray:
        """int16 codes (n, n_inputs) of stream frames first .. first + n - 1, waiting for
        them; OverrunError if the ring no longer holds them, DeviceDisconnectedError if the
        stream stopped or delivers nothing for timeout_s."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self.frames < first + n:
                self._check_alive()
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DeviceDisconnectedError(
                        f"{self.name} delivered no samples for {timeout_s:g} s (it stopped "
                        f"at stream frame {self.frames}): the device was unplugged or taken by "
                        "another program, or its audio server stopped")
                before = self.frames
                self._cond.wait(min(left, WAIT_SLICE_S))
                if self.frames > before:
                    deadline = time.monotonic() + timeout_s
        self._check_alive()  # a JACK device that left: its frames still come, silent
        size = self._ring.shape[0]
        index = np.arange(first, first + n) % size
        out = self._ring[index]
        if first < self.frames + 2 * self.max_block - size:  # overwritten while waiting or copying
            raise OverrunError(
                f"{self.name}: samples from stream frame {first} were overwritten before they "
                f"were read (the reader fell more than {size / self.rate_hz:.1f} s behind)")
        return out

    def faults_between(self, start: int, stop: int) -> list[Fault]:
        """The flagged xruns at frames start < f <= stop (samples lost before frame f)."""
        with self._cond:
            return [f for f in self.faults if start < f.frame <= stop]

    def _check_alive(self) -> None:
        if self._watch is not None and self._watch.gone is not None and not self._closed:
            raise DeviceDisconnectedError(
                f"{self.name} went away at stream frame {self.frames}: {self._watch.gone}; "
                "reconnect it (or restart the server), then capture again (after a server "
                "restart, restart the daemon and resume)")
        if not self._stream.active and not self._closed:
            raise DeviceDisconnectedError(
                f"{self.name} stopped at stream frame {self.frames}: the device was "
                "unplugged or taken by another program, or its audio server went away; "
                "reconnect it (or restart the server), then restart the daemon and resume")

    def close(self) -> None:
        """Stop and close the stream; a stream that died is left alone (PortAudio may hang
        stopping a stream whose JACK server went away)."""
        if self._closed:
            return
        dead = not self._stream.active
        self._closed = True
        if dead:  # its watch too: leaving a server that died may hang as well
            abandon()
            return
        if self._watch is not None:
            self._watch.close()
        try:
            self._stream.close()
        except Exception:  # a device gone between the check and the call: nothing to free
            pass
        stream_closed()

    def _release(self) -> None:
        self._closed = True
        if self._watch is not None:
            self._watch.close()
        try:
            self._stream.close()
        finally:
            stream_closed()
