"""A sync group scanning continuously: aligned blocks of every board, read as they come.

The capture path records finite scans (`SyncGroup.acquire`); the live view needs the boards to
run until told to stop, with no output played. `GroupStream` configures every board of a
group for an endless scan (inputs only, `samples_per_channel` None), arms the followers and
then the master exactly as `acquire` does, and hands out aligned blocks with the same check:
every board must deliver the same sample indices. A board's overrun or disappearance is raised
as the board raised it (`OverrunError`, `DeviceDisconnectedError`), naming board and sample.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._config import ScanConfig
from ._errors import BoardStateError, ConfigurationError
from ._sync import SyncGroup, read_aligned


class GroupStream:
    """An endless scan of every board of `group` (module docstring).

    Args:
        group: the boards.
        configs: one configuration per board; only their inputs and sample rate are used.
    """

    def __init__(self, group: SyncGroup, configs: Sequence[ScanConfig]) -> None:
        if len(configs) != len(group.boards):
            raise ConfigurationError(f"{len(configs)} scan configurations given for "
                                     f"{len(group.boards)} boards")
        self.group = group
        self._configs = [c.model_copy(update={"outputs": (), "samples_per_channel": None})
                         for c in configs]
        self.widths = [len(c.inputs) for c in self._configs]
        self.sample_rate_hz = float(self._configs[0].sample_rate_hz)
        self.index = 0  # the next sample to read
        self.running = False

    @property
    def n_columns(self) -> int:
        return int(sum(self.widths))

    def start(self) -> None:
        """Configure, arm the followers, then the master, and start the scan."""
        if self.running:
            raise BoardStateError("the stream is already running")
        self.group.configure(self._configs)
        master = self.group.boards[self.group.master]
        for i, board in enumerate(self.group.boards):
            if i != self.group.master:
                board.arm()
        master.arm()
        master.start()
        self.index = 0
        self.running = True

    def read(self, n_samples: int, timeout_s: float = 5.0) -> np.ndarray:
        """The next n_samples of every board: int16 codes (n_samples, n_columns), board after
        board in group order. On any error the stream is stopped before it is raised."""
        if not self.running:
            raise BoardStateError("the stream is not running; start it first")
        try:
            blocks = read_aligned(self.group.boards, self.index, n_samples, timeout_s)
        except Exception:
            self.stop()
            raise
        self.index += n_samples
        return np.concatenate(blocks, axis=1)

    def stop(self) -> None:
        """Stop every board (safe to call twice, and after a board failed)."""
        self.running = False
        for board in self.group.boards:
            try:
                board.stop()
            except Exception:  # an unplugged board: the others must still stop
                continue
