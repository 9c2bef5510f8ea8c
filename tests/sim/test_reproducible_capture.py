"""A simulated capture resumed in a fresh world records exactly what an uninterrupted capture
with the same seed records: the noise is keyed by what is captured, not by how many scans and
frames a process made (sim.setups)."""

from __future__ import annotations

from pathlib import Path

import pytest

from acquisition.contracts.camera import CameraError
from acquisition.contracts.session import SessionReader
from micam.simulated import prepare_simulated_capture, record_simulated_session
from sim.capture import SimulationOptions


def _checksums(session: Path) -> dict[str, dict[str, str]]:
    return {step: {name: f.sha256 for name, f in record.files.items()}
            for step, record in SessionReader(session).steps().items()}


def test_a_resumed_capture_records_what_an_uninterrupted_one_does(
        tmp_path: Path, small_options: SimulationOptions) -> None:
    """In the realistic lab: every random draw (inputs, images, the ambient noise) counts."""
    options = small_options.model_copy(update={"lab": "realistic"})
    record_simulated_session(tmp_path / "whole", options)

    cut = tmp_path / "cut"
    sim, sequencer = prepare_simulated_capture(cut, options)

    def fail_the_next_pose(progress) -> None:
        if progress.step == "pose/0000":
            sim.cameras[0].fail_next_grabs = 1  # pose/0001 fails at its first image

    sequencer.on_progress = fail_the_next_pose
    with pytest.raises(CameraError):
        sequencer.run()
    sequencer.writer.close()
    assert "pose/0001" not in SessionReader(cut).steps()

    _, resumed = prepare_simulated_capture(cut, None)  # a fresh world, as in a new process
    resumed.run()
    resumed.writer.close()
    assert SessionReader(cut).steps()["pose/0001"].attempt == 2
    assert _checksums(cut) == _checksums(tmp_path / "whole")
