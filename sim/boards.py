"""Simulated boards: the `daq.Board` protocol on the simulated bench.

A simulated board behaves like the real one where the capture code can tell: it refuses a
configuration its model cannot do, needs the calls in the right order, waits for the shared
trigger when configured for it, delivers exactly the samples asked for, and can be told to fail
the way hardware fails (unplugged, FIFO overrun, no trigger) so that those outcomes are tested.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daq import (
    Block,
    BoardCall,
    BoardIdentity,
    BoardStateError,
    CallOrder,
    ClosesOnExit,
    ConfigurationError,
    DeviceDisconnectedError,
    OverrunError,
    ScanConfig,
    TriggerSource,
    TriggerTimeoutError,
    board_model,
)

from .arrays import BoardSpec
from .analog_bench import AcousticBench


@dataclass
class BoardFaults:
    """Failures to inject into a simulated board (each fires once, then clears).

    Attributes:
        unplug_at_sample: the board disappears when a read reaches this sample index.
        overrun_at_sample: the input FIFO overflows when a read reaches this sample index.
        miss_trigger: the board does not see the next trigger edge (a loose trigger cable).
    """

    unplug_at_sample: int | None = None
    overrun_at_sample: int | None = None
    miss_trigger: bool = False


class SimulatedBoard(ClosesOnExit):
    """One simulated DT9836 / DT9816 wired to an `AcousticBench`."""

    def __init__(self, spec: BoardSpec, bench: AcousticBench) -> None:
        self._identity = BoardIdentity(board_model(spec.model), spec.serial)
        self._bench = bench
        bench.board_index(spec.serial)  # fails early for a board that is not wired
        self.faults = BoardFaults()
        self._order = CallOrder(str(self._identity))
        self._config: ScanConfig | None = None
        self._pending_output: np.ndarray | None = None
        self._armed_after = 0
        self._scan: int | None = None
        self._index = 0

    @property
    def identity(self) -> BoardIdentity:
        return self._identity

    def configure(self, config: ScanConfig) -> None:
        self._order.check("configure")
        config.check_against(self._identity.model, self._identity.serial)
        self._config = config
        self._order.done("configure")

    def write(self, codes: np.ndarray) -> None:
        config = self._require("write")
        codes = np.asarray(codes)
        n_out = len(config.outputs)
        if codes.dtype != np.int16 or codes.ndim != 2 or codes.shape[1] != n_out:
            raise ConfigurationError(
                f"{self._identity}: output waveform must be int16 codes of shape (n, {n_out}); "
                f"got {codes.dtype} {codes.shape}"
            )
        self._pending_output = codes

    def arm(self) -> None:
        config = self._require("arm")
        if self._pending_output is not None:
            self._bench.load_output(self._identity.serial, [c.channel for c in config.outputs],
                                    self._pending_output, config.outputs[0].range_v)
            self._pending_output = None
        self._armed_after = self._bench.current_scan
        self._scan = None
        self._index = 0
        self._order.done("arm")

    def start(self) -> None:
        config = self._require("start")
        if config.trigger is not TriggerSource.SOFTWARE:
            raise BoardStateError(
                f"{self._identity}: start() releases a software trigger, but this board waits "
                "for the external trigger; start the master board instead"
            )
        self._scan = self._bench.fire_trigger()
        self._order.done("start")

    def read(self, n_samples: int, timeout_s: float) -> Block:
        config = self._require("read")
        if self._scan is None:
            self._scan = self._wait_for_trigger(timeout_s)
        limit = config.samples_per_channel
        if limit is not None and self._index + n_samples > limit:
            raise BoardStateError(
                f"{self._identity}: read of {n_samples} samples at index {self._index} runs past "
                f"the end of the {limit}-sample scan"
            )
        self._raise_injected_faults(n_samples)
        codes = self._bench.input_codes(self._identity.serial, config.inputs, self._scan,
                                        self._index, n_samples)
        block = Block(codes, self._index, self._identity)
        self._index += n_samples
        return block

    def stop(self) -> None:
        self._order.stop()

    def close(self) -> None:
        self._order.close()

    def _wait_for_trigger(self, timeout_s: float) -> int:
        if self.faults.miss_trigger:
            self.faults.miss_trigger = False
            scan = None
        else:
            scan = self._bench.wait_for_trigger(self._armed_after, timeout_s)
        if scan is None:
            raise TriggerTimeoutError(
                f"{self._identity}: no trigger within {timeout_s:.1f} s; check the trigger and "
                "clock cables to this board and that the master board started"
            )
        return scan

    def _raise_injected_faults(self, n_samples: int) -> None:
        end = self._index + n_samples
        f = self.faults
        if f.unplug_at_sample is not None and f.unplug_at_sample < end:
            at, f.unplug_at_sample = f.unplug_at_sample, None
            self._order.close()
            raise DeviceDisconnectedError(
                f"{self._identity}: the board disappeared from the bus at sample {at}; check its "
                "USB cable and power, then reconnect"
            )
        if f.overrun_at_sample is not None and f.overrun_at_sample < end:
            at, f.overrun_at_sample = f.overrun_at_sample, None
            raise OverrunError(
                f"{self._identity}: input FIFO overrun at sample {at}; the data after it is lost"
            )

    def _require(self, call: BoardCall) -> ScanConfig:
        """Check the call order (`daq.CallOrder`); the configuration every call but
        `configure` works on."""
        self._order.check(call)
        assert self._config is not None
        return self._config
