"""An audio interface as a `daq.Board` (and `daq.OutputBoard` when it has outputs).

The board's model is what PortAudio says of the device (its name, channel counts, default
rate), its serial the label the configuration gives it (the `board` of the capture's columns
and speakers). Call order and meaning are those of every board: `configure` checks the scan
against the device (channels it has, a rate PortAudio accepts for it); `write` queues the
output burst; `arm` starts the device's stream if it is not running yet (it then keeps
running, `daq.audio._stream`); `start` places the recording window a little ahead of the
stream's clock, the output burst starting on the window's first sample; `read` hands out the
window's samples as they arrive; `stop` ends the window (the stream runs on). On a shared word
clock (`WordClock`) the master's `start` places every follower's window too.

Input codes are the interface's samples at 16 bits: code 32767 is digital full scale, so a
column's `range_v` is the voltage at the input that reaches full scale at the interface's
gain setting (an output's, the voltage its full scale drives).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from daq import (
    CODE_FULL_SCALE,
    Block,
    BoardIdentity,
    BoardModel,
    BoardStateError,
    CallOrder,
    ClockSource,
    ClosesOnExit,
    ConfigurationError,
    DeviceDisconnectedError,
    OverrunError,
    ScanConfig,
    TriggerSource,
    TriggerTimeoutError,
    UnderrunError,
)

from ._clock import WordClock
from ._devices import AudioDeviceInfo
from ._portaudio import portaudio
from ._stream import DuplexStream, Fault, refused


@dataclass(frozen=True)
class AudioIdentity(BoardIdentity):
    """An audio interface: its label (the serial of a board entry) and PortAudio's name."""

    host_api: str = ""

    def __str__(self) -> str:
        return f'audio interface {self.serial} ("{self.model.name}", {self.host_api})'


def device_model(device: AudioDeviceInfo) -> BoardModel:
    """The board model of a device: its channel counts and default rate."""
    return BoardModel(name=device.name, family="audio", n_inputs=device.inputs,
                      n_outputs=device.outputs, input_ranges_v=(), output_range_v=None,
                      max_input_rate_hz=device.default_rate_hz,
                      max_output_rate_hz=device.default_rate_hz if device.outputs else 0.0,
                      input_fifo_samples=0)


class AudioBoard(ClosesOnExit):
    """One audio interface (module docstring).

    Args:
        device: the device, as `find_device` found it.
        label: its name in the capture configuration (the boards' serial).
        block_frames: frames per callback (0: the host API's choice).
        latency: PortAudio's suggested latency, "low", "high" or seconds.
        clock: the word clock shared with the other interfaces of the group, if several.
    """

    def __init__(self, device: AudioDeviceInfo, label: str, block_frames: int = 0,
                 latency: str | float = "high", clock: WordClock | None = None) -> None:
        self.device = device
        self._identity = AudioIdentity(device_model(device), label, device.host_api)
        self._block_frames = block_frames
        self._latency = latency
        self._clock = clock
        if clock is not None:
            clock.join(self)
        self._order = CallOrder(str(self._identity))
        self._config: ScanConfig | None = None
        self._stream: DuplexStream | None = None
        self._waveform: np.ndarray | None = None  # int16 codes of the configured outputs
        self._window: int | None = None  # stream frame of sample 0
        self._placed = threading.Event()
        self._next = 0

    @property
    def identity(self) -> BoardIdentity:
        return self._identity

    @property
    def stream(self) -> DuplexStream:
        assert self._stream is not None, "the stream runs from arm() on"
        return self._stream

    @property
    def armed(self) -> bool:
        """Between `arm` and `stop`."""
        return self._order.scanning

    # -- the daq.Board protocol ---------------------------------------------------------------

    def configure(self, config: ScanConfig) -> None:
        self._order.check("configure")
        where, dev = str(self._identity), self.device
        for kind, channels, have in (("input", config.inputs, dev.inputs),
                                     ("output", config.outputs, dev.outputs)):
            for ch in channels:
                if ch.channel >= have:
                    raise ConfigurationError(
                        f"{where}: {kind} channel {ch.channel} does not exist; the device has "
                        + (f"{kind}s 0..{have - 1}" if have else f"no {kind}s"))
        if (config.clock is ClockSource.EXTERNAL or config.trigger is TriggerSource.EXTERNAL
                ) and self._clock is None:
            raise ConfigurationError(
                f"{where}: several interfaces record together only on one word clock; wire "
                "them to it and set [hardware.audio] word_clock = true")
        n_in = max(c.channel for c in config.inputs) + 1
        n_out = max((c.channel for c in config.outputs), default=-1) + 1
        self._check_settings(config.sample_rate_hz, n_in, n_out)
        s = self._stream
        if s is not None and (s.rate_hz != config.sample_rate_hz or s.n_inputs < n_in
                              or s.n_outputs < n_out or not s.alive):
            s.close()
            self._stream = None
        self._config = config
        self._waveform = None
        self._order.done("configure")

    def _check_settings(self, rate_hz: float, n_in: int, n_out: int) -> None:
        sd = portaudio()
        try:
            sd.check_input_settings(device=self.device.index, channels=n_in, dtype="float32",
                                    samplerate=rate_hz)
            if n_out:
                sd.check_output_settings(device=self.device.index, channels=n_out,
                                         dtype="float32", samplerate=rate_hz)
        except sd.PortAudioError as exc:
            raise refused(self.device, rate_hz, n_in, n_out, exc) from None

    def write(self, codes: np.ndarray) -> None:
        self._order.check("write")
        config = self._config
        assert config is not None
        codes = np.asarray(codes)
        if not config.outputs:
            raise ConfigurationError(f"{self._identity}: no outputs are configured")
        if codes.dtype != np.int16 or codes.ndim != 2 or codes.shape[1] != len(config.outputs):
            raise ConfigurationError(
                f"{self._identity}: the output waveform must be int16 codes of shape (n, "
                f"{len(config.outputs)}), not {codes.dtype} {codes.shape}")
        self._waveform = codes

    def arm(self) -> None:
        self._order.check("arm")
        config = self._config
        assert config is not None
        stream = self._stream
        if stream is not None and not stream.alive:
            raise DeviceDisconnectedError(
                f"{self._identity} stopped (unplugged, taken by another program, or its audio "
                "server went away); reconnect it, then restart the daemon and resume")
        if stream is None:
            n_in = max(c.channel for c in config.inputs) + 1
            n_out = max((c.channel for c in config.outputs), default=-1) + 1
            self._stream = DuplexStream(self.device, config.sample_rate_hz, n_in, n_out,
                                        self._block_frames, self._latency,
                                        name=str(self._identity))
        self._window = None
        self._placed.clear()
        self._next = 0
        self._order.done("arm")

    def start(self) -> None:
        self._order.check("start")
        assert self._config is not None
        if self._config.trigger is not TriggerSource.SOFTWARE:
            raise BoardStateError(
                f"{self._identity}: start() releases a software trigger, but this interface "
                "follows the master's; start the master instead")
        stream = self.stream
        stream.wait_running()
        window = stream.first_window()
        self.place_window(window)
        if self._clock is not None:
            self._clock.fire(self, window)
        # return at sample 0, as a board's scan starts on its start: a caller pacing its
        # reads by the clock from here (live mode) is then not behind by the lead
        stream.wait_frames(window, timeout_s=1.0 + (window - stream.frames) / stream.rate_hz)
        self._order.done("start")

    def place_window(self, window_frame: int) -> None:
        """Put sample 0 of the recording (and of the output burst) at `window_frame`."""
        config = self._config
        assert config is not None
        stream = self.stream
        samples = None
        if self._waveform is not None:
            samples = np.zeros((self._waveform.shape[0], stream.n_outputs), dtype=np.float32)
            for col, out in enumerate(config.outputs):
                samples[:, out.channel] = self._waveform[:, col] / CODE_FULL_SCALE
            self._waveform = None
        stream.play(window_frame, samples)
        self._window = window_frame
        self._placed.set()

    def read(self, n_samples: int, timeout_s: float) -> Block:
        self._order.check("read")
        config = self._config
        assert config is not None
        if not self._placed.wait(timeout_s):
            raise TriggerTimeoutError(
                f"{self._identity} saw no trigger within {timeout_s:.1f} s: the master "
                "interface did not start")
        assert self._window is not None
        total = config.samples_per_channel
        if total is not None and self._next + n_samples > total:
            raise BoardStateError(
                f"{self._identity}: asked for samples {self._next}..{self._next + n_samples - 1}"
                f" of a {total}-sample scan")
        stream, first = self.stream, self._window + self._next
        try:
            codes = stream.take(first, n_samples, timeout_s)
        except (OverrunError, DeviceDisconnectedError) as exc:
            raise type(exc)(f"{exc} (at sample index {self._next} of the recording)") from None
        end = first + n_samples
        if total is not None and self._next + n_samples == total:
            end = stream.wait_frames(end + stream.max_block, timeout_s)  # see _stream.Fault
        faults = stream.faults_between(self._window, end)
        if faults:
            self._raise_xrun(faults[0], playing=bool(config.outputs))
        block = Block(codes=codes[:, [c.channel for c in config.inputs]],
                      start_index=self._next, board=self._identity)
        self._next += n_samples
        return block

    def _raise_xrun(self, fault: Fault, playing: bool) -> None:
        assert self._window is not None
        index = fault.frame - self._window
        kinds = " and ".join(fault.kinds)
        why = (f"{self._identity}: {kinds} at sample index {index} (an xrun: the host was late "
               "and samples were lost); the recording is discarded: lower the load or raise the "
               "buffer (latency, block_frames), then capture again")
        if "input overflow" in fault.kinds or not playing:
            raise OverrunError(why)
        raise UnderrunError(why)

    def stop(self) -> None:
        if not self._order.stop():
            return
        if self._stream is not None:
            self._stream.play(0, None)
        self._window = None
        self._placed.clear()

    def close(self) -> None:
        if self._order.closed:
            return
        self.stop()
        if self._stream is not None:
            self._stream.close()
            self._stream = None
        self._order.close()
