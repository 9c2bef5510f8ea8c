"""The board interface every implementation (USB driver, simulated, emulated) satisfies.

Boards need no common base class: anything with these methods is a board (a runtime-checkable
Protocol, as in bluesky's protocols.py). Raw codes stay raw: a block carries signed 16-bit
codes, where code k means k / 32768 * range_v volts; `codes_to_volts` derives volts.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Protocol, Self, runtime_checkable

import numpy as np

from ._config import ScanConfig
from ._models import BoardModel

CODE_FULL_SCALE = 32768
"""Codes per full-scale range: code k stands for k / 32768 * range_v volts."""


@dataclass(frozen=True)
class BoardIdentity:
    """Which physical board this is: its model and its serial number."""

    model: BoardModel
    serial: str

    def __str__(self) -> str:
        return f"{self.model.name} serial {self.serial}"


@dataclass(frozen=True)
class Block:
    """A block of input samples from one board.

    Attributes:
        codes: int16 array of shape (n_samples, n_input_channels), channels in the order of the
            scan configuration.
        start_index: index of the first row, counted in samples from the trigger (0 = the first
            sample clock edge after the trigger).
        board: the identity of the board that produced it.
    """

    codes: np.ndarray
    start_index: int
    board: BoardIdentity

    @property
    def n_samples(self) -> int:
        return int(self.codes.shape[0])


class ClosesOnExit(ABC):
    """`with` for a resource that has `close()`: the end of the block closes it, whatever
    happened inside (boards, sync groups, cameras, session writers). A subclass without its
    own `close` cannot be instantiated."""

    @abstractmethod
    def close(self) -> None:
        """Release the resource."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


@runtime_checkable
class Board(Protocol):
    """One data-acquisition board (its inputs; a board with outputs is also an `OutputBoard`).

    Call order: configure -> (write) -> arm -> start -> read... -> stop; close at the end (or
    `with board:`). A board configured for an external trigger starts on the shared trigger
    edge after `arm`; `start` is only meaningful for a board on a software trigger (it
    releases the scan). Every implementation keeps this order with `daq.CallOrder`: a call out
    of order raises BoardStateError, any call after `close` DeviceDisconnectedError
    (tests/daq/test_board_conformance.py checks each board).
    """

    @property
    def identity(self) -> BoardIdentity: ...

    def configure(self, config: ScanConfig) -> None:
        """Validate and apply a scan configuration (ConfigurationError if impossible)."""

    def arm(self) -> None:
        """Get ready to sample: on an external trigger, wait for its edge from now on."""

    def start(self) -> None:
        """Release a software-triggered scan (the master of a sync group)."""

    def read(self, n_samples: int, timeout_s: float) -> Block:
        """Return the next `n_samples` samples, or raise (overrun, timeout, unplugged)."""

    def stop(self) -> None:
        """End the scan; the board can be armed again afterwards."""

    def close(self) -> None:
        """Release the board; no call is valid afterwards."""

    def __enter__(self) -> Self: ...

    def __exit__(self, *exc_info: object) -> None: ...


@runtime_checkable
class OutputBoard(Board, Protocol):
    """The capability of a board with analog outputs (a DT9836 driving the speakers)."""

    def write(self, codes: np.ndarray) -> None:
        """Queue an output waveform: int16 codes, shape (n_samples, n_output_channels)."""


def codes_to_volts(codes: np.ndarray, range_v: float | np.ndarray) -> np.ndarray:
    """Convert raw int16 codes to volts for a bipolar range of ±range_v volts."""
    return np.asarray(codes, dtype=np.float64) * (np.asarray(range_v) / CODE_FULL_SCALE)


def volts_to_codes(volts: np.ndarray, range_v: float) -> np.ndarray:
    """Quantize volts to int16 codes of a ±range_v range, clipping at full scale."""
    scaled = np.round(np.asarray(volts, dtype=np.float64) * (CODE_FULL_SCALE / range_v))
    return np.clip(scaled, -CODE_FULL_SCALE, CODE_FULL_SCALE - 1).astype(np.int16)

