"""The call order of a `daq.Board`, one state machine for every driver (simulated, USB, audio).

    configure -> (write) -> arm -> (start) -> read... -> stop -> arm ... ; close

A call out of order raises `BoardStateError` naming the call, the state and the states it
needs; any call after `close` (or after a driver found the board unplugged) raises
`DeviceDisconnectedError`. A driver asks `check` before it does the call's work and
`done` after it succeeded, so a call that fails leaves the state as it was.
"""

from __future__ import annotations

from enum import Enum
from typing import Literal

from ._errors import BoardStateError, DeviceDisconnectedError


class BoardState(Enum):
    """Where a board is in its call order."""

    IDLE = "idle"
    CONFIGURED = "configured"
    ARMED = "armed"
    RUNNING = "running"  # released by `start` (a software trigger)
    CLOSED = "closed"


BoardCall = Literal["configure", "write", "arm", "start", "read"]

_NEEDS: dict[BoardCall, tuple[BoardState, ...]] = {
    "configure": (BoardState.IDLE, BoardState.CONFIGURED),
    "write": (BoardState.CONFIGURED,),
    "arm": (BoardState.CONFIGURED,),
    "start": (BoardState.ARMED,),
    "read": (BoardState.ARMED, BoardState.RUNNING),
}
_AFTER: dict[BoardCall, BoardState] = {
    "configure": BoardState.CONFIGURED,
    "arm": BoardState.ARMED,
    "start": BoardState.RUNNING,
}
_DOING: dict[BoardCall, str] = {"write": "write an output waveform"}


class CallOrder:
    """The state of one board; `name` is how errors name the board."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.state = BoardState.IDLE

    def check(self, call: BoardCall) -> None:
        """Raise unless `call` may be made now."""
        if self.state is BoardState.CLOSED:
            raise DeviceDisconnectedError(f"{self.name}: the board is closed or unplugged")
        needs = _NEEDS[call]
        if self.state not in needs:
            raise BoardStateError(
                f"{self.name}: cannot {_DOING.get(call, call)} while {self.state.value} "
                f"(needs {' or '.join(s.value for s in needs)})"
            )

    def done(self, call: BoardCall) -> None:
        """`call` succeeded: move to the state it leads to."""
        self.state = _AFTER.get(call, self.state)

    @property
    def scanning(self) -> bool:
        """Between `arm` and `stop`."""
        return self.state in (BoardState.ARMED, BoardState.RUNNING)

    def stop(self) -> bool:
        """`stop` was called: back to configured; whether a scan was under way (else the
        call does nothing)."""
        if not self.scanning:
            return False
        self.state = BoardState.CONFIGURED
        return True

    def close(self) -> None:
        """The board was closed or found unplugged: no call is valid any more."""
        self.state = BoardState.CLOSED

    @property
    def closed(self) -> bool:
        return self.state is BoardState.CLOSED
