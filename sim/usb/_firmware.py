"""The emulated running firmware of a DT9836 / DT9816: commands, registers, streams, faults.

It parses the command packets with the driver's own protocol module (one definition of the
bytes for both sides), keeps a register file and the board EEPROM, answers read commands on
0x81, streams input frames on 0x82 computed by the `AnalogBench` for the current scan, takes the
DAC stream on 0x06 and hands it to the bench as the speaker signal when the output starts, and
posts asynchronous messages on 0x88. Where the real firmware's behaviour is not public it
follows the guesses of `daq.usb._unpublished`, so emulator and driver agree by construction and
a correction there moves both.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from daq import BoardModel, InputChannel
from daq.usb._ids import EP_CMD_IN, EP_MSG_IN, EP_STREAM_IN, VENDOR_ID
from daq.usb._protocol import (
    AsyncMessage,
    Command,
    MessageType,
    ReadI2cBytes,
    ReadWord,
    ReadWords,
    StartSubsystem,
    StopSubsystem,
    Subsystem,
    WriteWord,
    WriteWords,
    decode_command,
)
from daq.usb._registers import EEPROM_I2C_ADDRESS, IoOp, Reg
from daq.usb._unpublished import ScanSettings, decode_stream, encode_stream
from sim.analog_bench import AnalogBench

from ._clock import SharedClock
from ._errors import no_device, stall, timeout
from ._faults import Fault

_STREAM_FAULTS = ("unplug", "fifo_overflow", "stall")
_POLL_S = 0.02
"""How often a waiting transfer looks again at the scan (trigger, stop)."""


@dataclass
class _Scan:
    """One input scan from START_SUBSYSTEM(AD) to its stop."""

    settings: ScanSettings
    channels: tuple[InputChannel, ...]
    armed_after: int
    number: int | None = None
    produced: int = 0
    pending: bytes = b""
    stopped: bool = False
    dead: bool = False

    @property
    def frame_bytes(self) -> int:
        return 2 * len(self.channels)


class RunningFirmware:
    """The firmware side of one emulated board (everything after re-enumeration)."""

    def __init__(self, model: BoardModel, serial: str, eeprom_serial: int, version_id: int,
                 product_id: int, bench: AnalogBench, clock: SharedClock,
                 faults: Sequence[Fault], unplug: Callable[[], None]) -> None:
        """`serial` names the board on the bench; `eeprom_serial` is what the driver reads."""
        self.model = model
        self.serial = serial
        self.bench = bench
        self.clock = clock
        self._faults = list(faults)
        self._unplug = unplug
        self.registers: dict[int, int] = {Reg.VERSION_ID: version_id}
        header = bytes([0xC0, VENDOR_ID & 0xFF, VENDOR_ID >> 8, product_id & 0xFF,
                        product_id >> 8, 0, 0, 0])
        self.eeprom = header + eeprom_serial.to_bytes(4, "little") + bytes(4)
        self._cond = threading.Condition()
        self._replies: deque[bytes] = deque()
        self.messages: queue.Queue[bytes] = queue.Queue()
        self._dac = bytearray()
        self._scan: _Scan | None = None
        self._halted: set[int] = set()
        self._input_armed = False
        self._output_armed = False

    # -- OUT endpoints ------------------------------------------------------------------

    def command(self, packet: bytes) -> None:
        """A packet on 0x01: decode and execute it; an invalid one stalls the endpoint."""
        try:
            command = decode_command(packet)
        except Exception:
            raise stall() from None
        reply = self._execute(command)
        if reply is not None:
            fault = self._take_fault("corrupt_reply", lambda f: f.command == command.code)
            with self._cond:
                self._replies.append(reply[:-1] if fault else reply)
                self._cond.notify_all()

    def write_stream(self, data: bytes) -> None:
        """Bytes on 0x06: the DAC stream, kept until the output subsystem starts."""
        self._dac += data

    # -- IN endpoints -------------------------------------------------------------------

    def read(self, endpoint: int, size: int, timeout_s: float) -> bytes:
        if endpoint in self._halted:
            raise stall()
        deadline = time.monotonic() + timeout_s
        if endpoint == EP_CMD_IN:
            return self._read_reply(deadline)
        if endpoint == EP_MSG_IN:
            try:
                return self.messages.get(timeout=timeout_s)
            except queue.Empty:
                raise timeout() from None
        if endpoint == EP_STREAM_IN:
            return self._read_stream(size, deadline)
        raise stall()

    def clear_halt(self, endpoint: int) -> None:
        self._halted.discard(endpoint)

    # -- commands -----------------------------------------------------------------------

    def _execute(self, command: Command) -> bytes | None:
        match command:
            case ReadI2cBytes(reads=reads):
                return command.encode_reply([self.eeprom[reg] if dev == EEPROM_I2C_ADDRESS
                                             and reg < len(self.eeprom) else 0xFF
                                             for dev, reg in reads])
            case ReadWord(address=a):
                return command.encode_reply([self.registers.get(a, 0)])
            case ReadWords(addresses=addresses):
                return command.encode_reply([self.registers.get(a, 0) for a in addresses])
            case WriteWord(address=a, value=v):
                self._write_register(a, v)
            case WriteWords(writes=writes):
                for a, v in writes:
                    self._write_register(a, v)
            case StartSubsystem(subsystem=Subsystem.AD):
                self._start_input()
            case StartSubsystem(subsystem=Subsystem.DA):
                self._start_output()
            case StopSubsystem(subsystem=Subsystem.AD):
                self._stop_input()
            case StopSubsystem(subsystem=Subsystem.DA):
                self._dac.clear()
                self._output_armed = False
            case _:
                raise stall()
        return None

    def _write_register(self, address: int, value: int) -> None:
        if address == Reg.VERSION_ID:
            return  # read-only
        self.registers[address] = value
        if address != Reg.IO_OP_CONTROL:
            return
        io = IoOp(value)
        if IoOp.INPUT_SCAN_ARM in io:
            self._input_armed = True
        if IoOp.OUTPUT_ARM in io:
            self._output_armed = True
        if IoOp.INPUT_SOFT_TRIGGER in io:
            self._soft_trigger()
        if IoOp.INPUT_SCAN_STOP in io:
            self._stop_input()

    def _settings(self) -> ScanSettings:
        return ScanSettings.from_registers(lambda a: self.registers.get(a, 0))

    def _start_input(self) -> None:
        if not self._input_armed:
            raise stall()
        settings = self._settings()
        rng = 2.0 if settings.two_volt_range else 10.0
        channels = tuple(InputChannel(channel=c, range_v=rng) for c in settings.inputs)
        if not channels or max(settings.inputs) >= self.model.n_inputs:
            raise stall()
        with self._cond:
            self._scan = _Scan(settings, channels, armed_after=self.clock.last_scan)
            self._cond.notify_all()

    def _start_output(self) -> None:
        outputs = self._settings().outputs
        if not self._output_armed or not outputs or max(outputs) >= self.model.n_outputs:
            raise stall()
        whole = len(self._dac) - len(self._dac) % (2 * len(outputs))
        codes = decode_stream(bytes(self._dac[:whole]), len(outputs))
        self._dac.clear()
        assert self.model.output_range_v is not None
        self.bench.load_output(self.serial, outputs, codes, self.model.output_range_v)

    def _soft_trigger(self) -> None:
        scan = self._scan
        if (scan is None or scan.number is not None or scan.stopped
                or scan.settings.external_trigger or self._has_fault("missing_trigger")):
            return
        number = self.clock.fire(scan.settings.rate_hz)
        with self._cond:
            scan.number = number
            self._cond.notify_all()

    def _stop_input(self) -> None:
        self._input_armed = False
        with self._cond:
            if self._scan is not None:
                self._scan.stopped = True
            self._cond.notify_all()

    # -- reading ------------------------------------------------------------------------

    def _read_reply(self, deadline: float) -> bytes:
        with self._cond:
            while not self._replies:
                if not self._cond.wait(max(0.0, deadline - time.monotonic())):
                    raise timeout()
            return self._replies.popleft()

    def _read_stream(self, size: int, deadline: float) -> bytes:
        scan = self._scan
        while True:
            if scan is None or scan.dead or scan.number is None:
                if scan is not None and scan.stopped:
                    return b""  # the stop flushes a short packet
                self._wait(scan, deadline)
                scan = self._scan
                continue
            if scan.stopped:
                return b""  # a stopped scan's data is flushed
            total = scan.settings.samples or math.inf
            fault = self._next_stream_fault()
            cap = min(total, fault.at_sample if fault else math.inf)
            limit = min(cap, self.clock.edges(scan.number))
            want = -(-(size - len(scan.pending)) // scan.frame_bytes)
            n = int(max(0, min(want, limit - scan.produced)))
            if n < want and limit < cap:
                # real time: wait for the clock to produce the frames the transfer asks for
                pause = self.clock.seconds_for(scan.produced + want - limit)
                if time.monotonic() + pause > deadline:
                    time.sleep(max(0.0, deadline - time.monotonic()))
                    raise timeout()
                time.sleep(pause)
                continue
            if n == 0 and not scan.pending:
                if fault is not None and scan.produced >= fault.at_sample:
                    self._strike(fault, scan)
                    continue
                self._wait(scan, deadline)  # the finite scan is complete: the board idles
                continue
            if n:
                codes = self.bench.input_codes(self.serial, scan.channels, scan.number,
                                               scan.produced, n)
                scan.pending += encode_stream(codes)
                scan.produced += n
            out, scan.pending = scan.pending[:size], scan.pending[size:]
            return out

    def _wait(self, scan: _Scan | None, deadline: float) -> None:
        """Wait a little for the trigger or a state change; raise a timeout at the deadline."""
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise timeout()
        step = min(_POLL_S, remaining)
        if (scan is not None and scan.number is None and not scan.stopped and not scan.dead
                and scan.settings.external_trigger and not self._has_fault("missing_trigger")):
            number = self.clock.wait_for_trigger(scan.armed_after, step)
            if number is not None:
                scan.number = number
            return
        with self._cond:
            self._cond.wait(step)

    def _strike(self, fault: Fault, scan: _Scan) -> None:
        self._faults.remove(fault)
        if fault.kind == "unplug":
            self._unplug()
            raise no_device()
        if fault.kind == "stall":
            self._halted.add(EP_STREAM_IN)
            raise stall()
        scan.dead = True
        self.messages.put(AsyncMessage(MessageType.INPUT_FIFO_OVERFLOW).encode())

    # -- faults -------------------------------------------------------------------------

    def _has_fault(self, kind: str) -> bool:
        return any(f.kind == kind for f in self._faults)

    def _next_stream_fault(self) -> Fault | None:
        faults = [f for f in self._faults if f.kind in _STREAM_FAULTS]
        return min(faults, key=lambda f: f.at_sample) if faults else None

    def _take_fault(self, kind: str, match: Callable[[Fault], bool]) -> bool:
        for f in self._faults:
            if f.kind == kind and match(f):
                self._faults.remove(f)
                return True
        return False

