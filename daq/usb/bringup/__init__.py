"""The hardware bring-up kit: read USB captures and micam's traces, decode, compare, probe.

- `read_transfers(path)`: Linux usbmon captures (pcap and pcapng, link types 189 and 220),
  Windows USBPcap captures (249) and micam's own transfer traces, as `Transfer`s;
- `Decoder` / `decode`: each transfer decoded with the driver's protocol module (`Event`s);
- `diff_traces`: two traces aligned by their command sequence, every difference named with
  the guess of `daq/usb/_unpublished.py` (or the public fact) it contradicts;
- `probe`: a read-only look at every board on the bus, for a bring-up report.

`micam daq trace show|diff` and `micam daq probe` are the command line over these.
docs/usb-protocol.md, "Correcting the guesses against real hardware", is the procedure.
"""

from ._decode import Decoder, decode
from ._events import DeviceInfo, Event, Op
from ._diff import Difference, TraceDiff, diff_traces
from ._errors import TraceError, WriteRefusedError
from ._probe import ProbedBoard, ProbeReport, ReadOnlyChannel, probe
from ._read import read_transfers
from ._select import Selection, select
from ._transfer import Setup, Status, Transfer

__all__ = [
    "Decoder",
    "DeviceInfo",
    "Difference",
    "Event",
    "Op",
    "ProbeReport",
    "ProbedBoard",
    "ReadOnlyChannel",
    "Selection",
    "Setup",
    "Status",
    "TraceDiff",
    "TraceError",
    "Transfer",
    "WriteRefusedError",
    "decode",
    "diff_traces",
    "probe",
    "read_transfers",
    "select",
]
