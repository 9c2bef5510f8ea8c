"""Every resource is a context manager that closes on the way out, and outputs are a capability
of the boards that have them (a DT9816 need not pretend to write)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acquisition.contracts.session import SessionReader, SessionWriter
from daq import Board, OutputBoard, SyncGroup
from sim.capture import build_simulated_capture
from sim.cameras import SimulatedCamera

from micam.testing import small_options


def test_boards_group_and_cameras_close_at_the_end_of_a_with_block() -> None:
    sim = build_simulated_capture(small_options())
    boards = list(sim.group.boards)
    with sim.group as group:
        assert isinstance(group, SyncGroup)
    for board in boards:
        assert isinstance(board, Board)
    for camera in sim.cameras:
        assert isinstance(camera, SimulatedCamera)
        with camera:
            pass


def test_a_board_without_outputs_is_a_board_but_no_output_board() -> None:
    class InputsOnly:
        identity = None

        def configure(self, config: object) -> None: ...
        def arm(self) -> None: ...
        def start(self) -> None: ...
        def read(self, n_samples: int, timeout_s: float) -> object: ...
        def stop(self) -> None: ...
        def close(self) -> None: ...
        def __enter__(self) -> InputsOnly: return self
        def __exit__(self, *exc_info: object) -> None: ...

    assert isinstance(InputsOnly(), Board) and not isinstance(InputsOnly(), OutputBoard)
    sim = build_simulated_capture(small_options())
    with sim.group:
        assert any(isinstance(b, OutputBoard) for b in sim.group.boards)


def test_a_session_writer_closes_without_stopping(tmp_path: Path) -> None:
    with SessionWriter.create(tmp_path / "s", capture={}) as writer:
        writer.begin_step("pose/0000")
        writer.write_json("pose/0000", "x.json", {"a": np.int64(1).item()})
        writer.end_step("pose/0000")
    assert SessionReader(tmp_path / "s").status == "interrupted"
