"""micam's driver layer: board models, scan configurations, the board interface, sync groups.

The USB driver for real Data Translation boards lives in `daq.usb`, the audio-interface backend
(any device PortAudio reaches) in `daq.audio`; the simulated boards in `sim.boards`. Everything above this layer talks to the `Board` protocol only.
"""

from ._call_order import BoardCall, BoardState, CallOrder
from ._config import ClockSource, InputChannel, OutputChannel, ScanConfig, TriggerSource
from ._errors import (
    BoardStateError,
    ConfigurationError,
    DaqError,
    DeviceDisconnectedError,
    OverrunError,
    SyncError,
    TriggerTimeoutError,
    UnderrunError,
)
from ._interface import (
    CODE_FULL_SCALE,
    Block,
    Board,
    BoardIdentity,
    ClosesOnExit,
    OutputBoard,
    codes_to_volts,
    volts_to_codes,
)
from ._models import BOARD_MODELS, BoardModel, board_model
from ._selftest import ChannelLevel, SelftestReport, selftest
from ._stream import GroupStream
from ._sync import GroupRecording, SyncGroup

__all__ = [
    "BOARD_MODELS",
    "CODE_FULL_SCALE",
    "Block",
    "Board",
    "BoardCall",
    "BoardIdentity",
    "ClosesOnExit",
    "BoardModel",
    "BoardState",
    "BoardStateError",
    "CallOrder",
    "ChannelLevel",
    "ClockSource",
    "ConfigurationError",
    "DaqError",
    "DeviceDisconnectedError",
    "GroupRecording",
    "GroupStream",
    "InputChannel",
    "OutputChannel",
    "OutputBoard",
    "OverrunError",
    "SelftestReport",
    "ScanConfig",
    "SyncError",
    "SyncGroup",
    "TriggerSource",
    "TriggerTimeoutError",
    "UnderrunError",
    "board_model",
    "codes_to_volts",
    "selftest",
    "volts_to_codes",
]
