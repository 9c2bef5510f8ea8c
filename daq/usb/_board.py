"""The board model layer: a DT9836 or DT9816 on the USB driver, as a `daq.Board`.

On top of the wire protocol: identify the variant from the VERSION_ID register, read the serial
number from the board EEPROM, initialise the FPGA as Data Translation's driver does, turn a
`ScanConfig` into register settings (and read them back, because the scan set-up is a guess
that a board would silently ignore if wrong), write the output burst to the DAC stream before
the trigger, arm, release, stream and stop. The family (DT9836 or DT9816) is data
(`_families`); one class serves both, so a sync group drives them unchanged.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from daq import (
    Block,
    BoardIdentity,
    BoardStateError,
    CallOrder,
    ClockSource,
    ClosesOnExit,
    ConfigurationError,
    DaqError,
    DeviceDisconnectedError,
    ScanConfig,
    TriggerSource,
)

from ._channel import COMMAND_TIMEOUT_S, CommandChannel
from ._errors import ProtocolError, StalledEndpointError, TransferTimeoutError
from ._families import Family
from ._ids import EP_STREAM_IN, EP_STREAM_OUT
from ._protocol import ReadI2cBytes
from ._registers import BASE_CLOCK_HZ, EEPROM_I2C_ADDRESS, EEPROM_SERIAL, INIT_SEQUENCE, Reg
from ._stream import InputStream, MessageWatcher
from ._transport import UsbTransport
from ._unpublished import (
    ScanSettings,
    arm_commands,
    clock_period,
    encode_stream,
    software_trigger_commands,
    stop_commands,
)

DRAIN_BYTES = 64 * 1024
"""Size of one read that empties the input endpoint before a scan."""
DRAIN_READS = 64
"""More stale data than DRAIN_READS * DRAIN_BYTES means the board never stopped."""
DRAIN_TIMEOUT_S = 0.01
"""An idle endpoint answers a drain read with this timeout."""


class UsbBoard(ClosesOnExit):
    """One Data Translation board driven over USB; satisfies the `daq.Board` protocol."""

    def __init__(self, transport: UsbTransport, family: Family) -> None:
        """Identify and initialise an opened board whose firmware runs."""
        self._transport = transport
        self.family = family
        self.channel = CommandChannel(transport)
        self._identity = identify(self.channel, family)
        self.channel.write_registers(INIT_SEQUENCE)
        self._order = CallOrder(transport.name)
        self._config: ScanConfig | None = None
        self._settings: ScanSettings | None = None
        self._armed: ScanSettings | None = None
        self._input_order: list[int] = []
        self._output_order: list[int] = []
        self._waveform: np.ndarray | None = None
        self._stream: InputStream | None = None
        self._watcher = MessageWatcher(transport)
        self._watcher.start()
        self._next_index = 0

    @property
    def identity(self) -> BoardIdentity:
        return self._identity

    # -- the daq.Board protocol -------------------------------------------------------------

    def configure(self, config: ScanConfig) -> None:
        self._order.check("configure")
        model, where = self._identity.model, self._transport.name
        config.check_against(model, self._identity.serial)
        ranges = {c.range_v for c in config.inputs}
        if len(ranges) != 1:
            raise ConfigurationError(
                f"{where}: all inputs of this board share one range, but the scan asks for "
                f"{sorted(ranges)} V; choose one"
            )
        internal = config.clock is ClockSource.INTERNAL
        inputs = sorted(c.channel for c in config.inputs)
        outputs = sorted(c.channel for c in config.outputs)
        settings = ScanSettings(
            inputs=tuple(inputs),
            two_volt_range=ranges == {2.0},
            outputs=tuple(outputs),
            external_clock=not internal,
            external_trigger=config.trigger is TriggerSource.EXTERNAL,
            samples=config.samples_per_channel or 0,
            clock_period=(clock_period(config.sample_rate_hz, where) if internal
                          else max(1, round(BASE_CLOCK_HZ / config.sample_rate_hz))),
        )
        writes = settings.registers()
        self.channel.write_registers(writes)
        final = dict(writes)
        readback = self.channel.read_registers(list(final))
        wrong = [(a, v, r) for (a, v), r in zip(final.items(), readback, strict=True) if v != r]
        if wrong:
            detail = ", ".join(f"0x{a:03x}: wrote 0x{v:04x}, read 0x{r:04x}" for a, v, r in wrong)
            raise ProtocolError(
                f"{where} did not keep its scan settings ({detail}); the register guess in "
                "daq/usb/_unpublished.py may be wrong for this board: trace the transfers"
            )
        self._config, self._settings = config, settings
        self._input_order = [inputs.index(c.channel) for c in config.inputs]
        self._output_order = [config.outputs.index(c) for c in
                              sorted(config.outputs, key=lambda o: o.channel)]
        self._waveform = None
        self._order.done("configure")

    def write(self, codes: np.ndarray) -> None:
        self._order.check("write")
        config = self._config
        assert config is not None
        codes = np.asarray(codes)
        where = self._transport.name
        if not config.outputs:
            raise ConfigurationError(f"{where}: no outputs are configured; configure them first")
        if codes.dtype != np.int16 or codes.ndim != 2 or codes.shape[1] != len(config.outputs):
            raise ConfigurationError(
                f"{where}: the output waveform must be int16 codes of shape (n, "
                f"{len(config.outputs)}), not {codes.dtype} {codes.shape}"
            )
        self._waveform = codes[:, self._output_order]

    def arm(self) -> None:
        self._order.check("arm")
        config, settings = self._config, self._settings
        assert config is not None and settings is not None
        self._transport.clear_halt(EP_STREAM_IN)
        if self._waveform is not None:
            data = encode_stream(self._waveform)
            self._transport.bulk_write(EP_STREAM_OUT, data, COMMAND_TIMEOUT_S + len(data) / 1e6)
            self._armed = settings
        else:
            self._armed = dataclasses.replace(settings, outputs=())  # outputs hold 0 V
        self._waveform = None
        self._drain_stale_input()
        for command in arm_commands(self._armed):
            self.channel.send(command)
        self._stream = InputStream(self._transport, len(settings.inputs),
                                   config.samples_per_channel, config.sample_rate_hz)
        self._watcher.attach(self._stream)
        self._next_index = 0
        self._stream.start()
        self._order.done("arm")

    def _drain_stale_input(self) -> None:
        """Discard what an earlier scan left in the input endpoint: a stale byte would shift
        every frame of the new scan."""
        for _ in range(DRAIN_READS):
            try:
                if not self._transport.bulk_read(EP_STREAM_IN, DRAIN_BYTES, DRAIN_TIMEOUT_S):
                    return
            except TransferTimeoutError:
                return
        raise ProtocolError(
            f"{self._transport.name} still streams input data while stopped; replug the board"
        )

    def start(self) -> None:
        self._order.check("start")
        assert self._config is not None and self._armed is not None
        if self._config.trigger is TriggerSource.SOFTWARE:
            for command in software_trigger_commands(self._armed):
                self.channel.send(command)
        self._order.done("start")

    def read(self, n_samples: int, timeout_s: float) -> Block:
        self._order.check("read")
        assert self._stream is not None and self._config is not None
        total = self._config.samples_per_channel
        if total is not None and self._next_index + n_samples > total:
            raise BoardStateError(
                f"{self._transport.name}: asked for samples {self._next_index}.."
                f"{self._next_index + n_samples - 1} of a {total}-sample scan"
            )
        codes = self._stream.take(n_samples, timeout_s, self._next_index)
        block = Block(codes=codes[:, self._input_order], start_index=self._next_index,
                      board=self._identity)
        self._next_index += n_samples
        return block

    def stop(self) -> None:
        """End the scan. Errors of the stop commands are raised only if the scan itself had
        not already failed (its error is the one that matters, and `read` has raised it)."""
        stream, armed = self._stream, self._armed
        if not self._order.stop():
            return
        assert stream is not None and armed is not None
        failure = stream.failure
        stream.request_stop()
        try:
            self._send_stop(armed, failure)
        except DaqError:
            if failure is None:
                raise
        finally:
            stream.close()
            self._watcher.attach(None)
            self._stream = None

    def _send_stop(self, armed: ScanSettings, failure: DaqError | None) -> None:
        if isinstance(failure, DeviceDisconnectedError):
            return
        if isinstance(failure, StalledEndpointError):
            self._transport.clear_halt(EP_STREAM_IN)
        for command in stop_commands(armed):
            self.channel.send(command)

    def close(self) -> None:
        if self._order.closed:
            return
        try:
            self.stop()
        except DaqError:
            pass  # closing releases the board whatever state it is in
        finally:
            self._watcher.close()
            self._transport.close()
            self._order.close()


def identify(channel: CommandChannel, family: Family) -> BoardIdentity:
    """Read the variant (VERSION_ID register) and the serial number (EEPROM) of a board, and
    name the channel's transport after it so that every later error names the board."""
    name = channel.transport.name
    version = channel.read_registers([Reg.VERSION_ID])[0]
    model = family.model(version)
    if model is None:
        known = ", ".join(f"0x{v:04x} {n}" for v, n in family.variants.items())
        raise ProtocolError(
            f"{name}: its version register reads 0x{version:04x}, which names no known "
            f"{family.name} variant ({known}); add it to the family table"
        )
    serial = channel.send(ReadI2cBytes(tuple((EEPROM_I2C_ADDRESS, r) for r in EEPROM_SERIAL)))
    identity = BoardIdentity(model, str(int.from_bytes(bytes(serial), "little")))
    channel.transport.name = str(identity)
    return identity
