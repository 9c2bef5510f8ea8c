"""Several boards on one shared sample clock and trigger, read as one aligned recording.

Wiring assumed (as in the Legg & Bradley set-up): the master board runs on its own time base and
drives the shared clock and trigger lines; every follower samples on the external clock and
starts on the external trigger. Followers are armed first, the master last, so no follower can
miss the trigger edge. Every block is checked: all boards must deliver the same sample indices,
and any mismatch is a SyncError naming the board and the sample index.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from ._config import ClockSource, ScanConfig, TriggerSource
from ._errors import BoardStateError, ConfigurationError, SyncError
from ._interface import Board, BoardIdentity, ClosesOnExit, OutputBoard


@dataclass(frozen=True)
class GroupRecording:
    """One synchronized acquisition of every board.

    Attributes:
        codes: int16 array (n_samples, total input channels): board after board, each board's
            channels in its scan-configuration order.
        boards: the identities of the boards, in column order.
        columns: for each board, the slice of `codes` columns that holds its channels.
    """

    codes: np.ndarray
    boards: tuple[BoardIdentity, ...]
    columns: tuple[slice, ...]


def read_aligned(boards: Sequence[Board], index: int, n: int, timeout_s: float
                 ) -> list[np.ndarray]:
    """The next n samples of every board (codes, one array per board), checked to be samples
    index .. index + n - 1 on all of them; a SyncError names the first board that is not."""
    out = []
    for board in boards:
        block = board.read(n, timeout_s)
        if block.start_index != index or block.n_samples != n:
            raise SyncError(
                f"board {board.identity} delivered samples {block.start_index}.."
                f"{block.start_index + block.n_samples - 1} where the group expected "
                f"{index}..{index + n - 1}: the boards are no longer aligned"
            )
        out.append(block.codes)
    return out


class SyncGroup(ClosesOnExit):
    """Runs several boards as one instrument on a shared clock and trigger."""

    def __init__(self, boards: Sequence[Board], master: int = 0) -> None:
        if not boards:
            raise ConfigurationError("a sync group needs at least one board")
        if not 0 <= master < len(boards):
            raise ConfigurationError(
                f"master index {master} is out of range for {len(boards)} boards"
            )
        serials = [b.identity.serial for b in boards]
        if len(set(serials)) != len(serials):
            raise ConfigurationError(f"a board is listed twice in the sync group: {serials}")
        self.boards: tuple[Board, ...] = tuple(boards)
        self.master = master
        self._configs: tuple[ScanConfig, ...] | None = None

    def configure(self, configs: Sequence[ScanConfig]) -> None:
        """Configure every board; clock and trigger roles are set here, not by the caller.

        All boards must use the same sample rate and scan length: they share one clock.
        """
        if len(configs) != len(self.boards):
            raise ConfigurationError(
                f"{len(configs)} scan configurations given for {len(self.boards)} boards"
            )
        rates = {c.sample_rate_hz for c in configs}
        lengths = {c.samples_per_channel for c in configs}
        if len(rates) != 1 or len(lengths) != 1:
            raise ConfigurationError(
                "boards on a shared clock need one sample rate and one scan length; got rates "
                f"{sorted(rates)} and lengths {sorted(lengths, key=str)}"
            )
        applied = []
        for i, (board, cfg) in enumerate(zip(self.boards, configs, strict=True)):
            if i == self.master:
                cfg = cfg.model_copy(
                    update={"clock": ClockSource.INTERNAL, "trigger": TriggerSource.SOFTWARE}
                )
            else:
                cfg = cfg.model_copy(
                    update={"clock": ClockSource.EXTERNAL, "trigger": TriggerSource.EXTERNAL}
                )
            board.configure(cfg)
            applied.append(cfg)
        self._configs = tuple(applied)

    @property
    def configs(self) -> tuple[ScanConfig, ...]:
        if self._configs is None:
            raise BoardStateError("the sync group has not been configured")
        return self._configs

    def acquire(
        self,
        outputs: Mapping[int, np.ndarray] | None = None,
        block_samples: int = 8192,
        timeout_s: float = 5.0,
    ) -> GroupRecording:
        """Play `outputs` (board index -> int16 codes) and record one finite scan on all boards.

        The outputs are written before any board is armed, so they start on the trigger edge,
        sample-synchronous with the inputs.
        """
        configs = self.configs
        n_total = configs[0].samples_per_channel
        if n_total is None:
            raise ConfigurationError("acquire() needs a finite scan (samples_per_channel)")
        for index, codes in (outputs or {}).items():
            if not configs[index].outputs:
                raise ConfigurationError(
                    f"board {self.boards[index].identity} has no outputs configured but an "
                    "output waveform was given for it"
                )
            board = self.boards[index]
            if not isinstance(board, OutputBoard):
                raise ConfigurationError(f"board {board.identity} has no analog outputs")
            board.write(codes)
        followers = [b for i, b in enumerate(self.boards) if i != self.master]
        master = self.boards[self.master]
        chunks: list[list[np.ndarray]] = [[] for _ in self.boards]
        try:
            for board in followers:
                board.arm()
            master.arm()
            master.start()
            index = 0
            while index < n_total:
                n = min(block_samples, n_total - index)
                for k, codes in enumerate(read_aligned(self.boards, index, n, timeout_s)):
                    chunks[k].append(codes)
                index += n
        finally:
            for board in self.boards:
                board.stop()
        per_board = [np.concatenate(c, axis=0) for c in chunks]
        widths = [p.shape[1] for p in per_board]
        edges = np.concatenate([[0], np.cumsum(widths)])
        return GroupRecording(
            codes=np.concatenate(per_board, axis=1),
            boards=tuple(b.identity for b in self.boards),
            columns=tuple(slice(int(a), int(b)) for a, b in pairwise(edges)),
        )

    def close(self) -> None:
        for board in self.boards:
            board.close()
