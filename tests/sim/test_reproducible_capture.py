"""A simulated capture resumed in a fresh world records exactly what an uninterrupted capture
with the same seed records: the noise is keyed by what is captured, not by how many scans and
frames a process made (sim.setups)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from acquisition.contracts.camera import CameraError
from acquisition.contracts.session import SessionReader
from micam.simulated import prepare_simulated_capture, record_simulated_session
from sim.cameras import SimulatedCamera
from sim.capture import SimulationOptions


def _checksums(session: Path) -> dict[str, dict[str, str]]:
    return {step: {name: f.sha256 for name, f in record.files.items()}
            for step, record in SessionReader(session).steps().items()}


MISTAKES = ("swap-mics", "swap-speakers", "moved-pose=0", "intermittent-mic=5,0.5",
            "close-reflector", "distorted-speaker", "refmic-far", "clipped-bursts",
            "hidden-board=1", "motion-blur=1", "mjpeg")
"""One mistake of each layer (cables, rig, capsules, speakers, inputs, scene, codec), the
scene's at pose 1, made again in its resumed attempt (the rig moved at pose 0: an image
mistake is not made at a moved pose)."""


@pytest.mark.parametrize("mistakes", [(), MISTAKES], ids=["clean", "mistakes"])
@pytest.mark.slow
def test_a_resumed_capture_records_what_an_uninterrupted_one_does(
        tmp_path: Path, small_options: SimulationOptions, mistakes: tuple[str, ...]) -> None:
    """In the realistic lab: every random draw (inputs, images, the ambient noise, the
    mistakes' choices) counts."""
    options = small_options.model_copy(update={"lab": "realistic", "mistakes": mistakes})
    record_simulated_session(tmp_path / "whole", options)

    cut = tmp_path / "cut"
    sim, sequencer = prepare_simulated_capture(cut, options)
    camera = sim.cameras[0]
    assert isinstance(camera, SimulatedCamera)

    def fail_the_next_pose(progress) -> None:
        if progress.step == "pose/0000":
            camera.fail_next_grabs = 1  # pose/0001 fails at its first image

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


@pytest.mark.parametrize(("change", "message"), [
    (lambda t: b"{not json", "it is not a JSON object with the simulation's options"),
    (lambda t: b"[1, 2]", "it is not a JSON object with the simulation's options"),
    (lambda t: json.dumps({**t, "simulation": None}).encode(), "not a JSON object"),
    (lambda t: json.dumps({**t, "simulation": {**t["simulation"], "mistakes": [5]}}).encode(),
     "its simulation option mistakes.0 is not valid"),
    (lambda t: json.dumps({**t, "simulation": {**t["simulation"], "poses": "x"}}).encode(),
     "its simulation option poses is not valid"),
    (lambda t: json.dumps({**t, "simulation": {**t["simulation"], "mistakes": ["dead-mic=99"]}}
                          ).encode(), "there is no microphone 99"),
], ids=["not-json", "a-list", "no-options", "mistake-type", "poses-type", "no-such-mic"])
def test_a_resume_from_a_changed_truth_is_refused_in_one_line(
        tmp_path: Path, small_options: SimulationOptions, capsys: pytest.CaptureFixture,
        change: Callable[[dict], bytes], message: str) -> None:
    """truth.json is a file anyone who can write the session may change: `--resume` refuses
    one that holds no valid options as bad input (exit 2, one line), never as a bug."""
    from micam.cli import main

    session = tmp_path / "s"
    _, sequencer = prepare_simulated_capture(session, small_options)
    sequencer.writer.close()  # an interrupted session: nothing captured yet
    truth = session / "truth.json"
    truth.write_bytes(change(json.loads(truth.read_text())))
    assert main(["simulate", "--resume", "--out", str(session), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("micam: error: ") and message in err and err.count("\n") == 1
