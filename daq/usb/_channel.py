"""The command channel: one command packet and its reply at a time, over endpoints 0x01/0x81.

This is the wire protocol bound to a transport: it serialises each command with its reply
(the reader threads share the device), checks every reply against the protocol, and offers
register reads and writes in as few packets as the protocol allows.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Iterator, Sequence
from typing import TypeVar

from ._errors import ProtocolError
from ._ids import COMMAND_PACKET_BYTES, EP_CMD_IN, EP_CMD_OUT
from ._protocol import Command, ReadWord, ReadWords, WriteWords
from ._transport import UsbTransport

COMMAND_TIMEOUT_S = 5.0
"""Timeout of a command write and of its reply (Data Translation's driver: 5 s)."""

T = TypeVar("T")


class CommandChannel:
    """Commands to one board; every method raises driver errors that name the board."""

    def __init__(self, transport: UsbTransport) -> None:
        self.transport = transport
        self._lock = threading.Lock()

    def send(self, command: Command) -> tuple[int, ...]:
        """Send one command; for a read command, return its decoded reply (else ())."""
        with self._lock:
            self.transport.bulk_write(EP_CMD_OUT, command.encode(), COMMAND_TIMEOUT_S)
            if not hasattr(command, "reply_length"):
                return ()
            reply = self.transport.bulk_read(EP_CMD_IN, COMMAND_PACKET_BYTES,
                                             COMMAND_TIMEOUT_S)
        try:
            return command.decode_reply(reply)  # type: ignore[attr-defined, no-any-return]
        except ProtocolError as e:
            raise ProtocolError(f"{self.transport.name}: {e}; replug the board and retry, "
                                "and trace the transfers if it persists") from None

    def read_registers(self, addresses: Sequence[int]) -> tuple[int, ...]:
        """Read FPGA registers (R_SINGLE_WORD_LB for one, R_MULTI_WORD_LB for several)."""
        if len(addresses) == 1:
            return self.send(ReadWord(addresses[0]))
        values: list[int] = []
        for chunk in chunks(addresses, ReadWords.MAX):
            values += self.send(ReadWords(tuple(chunk)))
        return tuple(values)

    def write_registers(self, writes: Iterable[tuple[int, int]]) -> None:
        """Write FPGA registers in order (W_MULTI_WORD_LB, 14 per packet)."""
        for chunk in chunks(list(writes), WriteWords.MAX):
            self.send(WriteWords(tuple(chunk)))


def chunks(items: Sequence[T], size: int) -> Iterator[Sequence[T]]:
    """Consecutive slices of at most `size` items."""
    for i in range(0, len(items), size):
        yield items[i: i + size]
