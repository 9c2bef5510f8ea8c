"""`micam config template`: each template validates as written, states the set-up it names,
and (the daemon's) drives a first capture: its capture configuration, unchanged but for a
short burst and one pose, runs the real capture sequencer on simulated boards of its models
and serials, and the session calibration reads has the template's layout."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from micam.cli import main
from micam.hardware import load_daemon_config as load_config
from acquisition.importer import load_spec
from micam.templates import PLACEHOLDER, TEMPLATES, template
from daq import board_model


def _written(tmp_path: Path, name: str) -> Path:
    out = tmp_path / f"{name}.toml"
    assert main(["config", "template", name, "--out", str(out)]) == 0
    assert out.read_text() == template(name)
    return out


@pytest.mark.parametrize("name", TEMPLATES)
def test_each_template_passes_its_check_once_its_placeholders_are_filled_in(
        tmp_path: Path, name: str, capsys: pytest.CaptureFixture) -> None:
    """As written, a template with a placeholder (a device only the lab can name) is refused
    and each place named; with real values in them it passes."""
    path = _written(tmp_path, name)
    text = path.read_text()
    if PLACEHOLDER in text:
        assert main(["config", "check", str(path)]) == 2
        err = capsys.readouterr().err
        assert f"still the template's {PLACEHOLDER} at " in err and err.count("\n") == 1
        assert "device" in err
        path.write_text(text.replace(PLACEHOLDER, "lab-value"))
    assert main(["config", "check", str(path)]) == 0
    assert "OK" in capsys.readouterr().out
    assert main(["config", "template", name, "--out", str(path)]) == 2  # never overwritten


def test_the_paper_template_is_the_papers_set_up(tmp_path: Path) -> None:
    config = load_config(_written(tmp_path, "paper"))
    hw = config.hardware
    assert hw is not None
    capture = hw.capture
    assert Counter(b.model for b in capture.boards) == {"DT9836-12-2": 3, "DT9816-A": 7}
    assert sum(c.role == "mic" for c in capture.columns) == 72
    reference_board = capture.reference.board
    assert all(c.board == reference_board for c in capture.columns if c.role == "reference")
    assert not any(c.board == reference_board for c in capture.columns if c.role == "mic")
    assert [c.name for c in hw.cameras] == ["cam0", "cam1", "cam2"]
    for board in capture.boards:  # every board uses only what its model has
        model = board_model(board.model)
        assert len(board.inputs) <= model.n_inputs and len(board.outputs) <= model.n_outputs


def test_the_generic_template_records_the_reference_on_an_array_board(tmp_path: Path) -> None:
    capture = load_config(_written(tmp_path, "generic")).hardware.capture  # type: ignore
    d = capture.description({"cam0": (1280, 960)})
    assert d.reference.group in {g.group for g in d.channels}  # an array board: the gauge
    assert d.reference_on_poses and len(d.microphones()) == 35


def test_the_import_template_describes_an_import(tmp_path: Path) -> None:
    spec = load_spec(_written(tmp_path, "import"))
    assert spec.n_speakers == 6 and spec.air is not None
    assert not spec.reference_on_poses


@pytest.mark.parametrize("name", ["paper", "generic"])
@pytest.mark.slow
def test_a_daemon_template_drives_a_first_capture(tmp_path: Path, name: str) -> None:
    from acquisition.contracts.burst import BurstConfig
    from acquisition.sequencer import CaptureSequencer
    from acquisition.contracts.session import SessionWriter
    from calibration.session_data import load_session
    from daq import SyncGroup
    from sim.arrays import ArrayLayout, BoardSpec, ChannelRef, fibonacci_sphere, sphere72
    from sim.analog_bench import AcousticBench
    from sim.boards import SimulatedBoard
    from sim.cameras import SimulatedCamera
    from sim.geometry import Rig
    from sim.simulated_operator import SimulatedOperator, reference_stand_position
    from sim.poses import sample_poses
    from sim.world import World

    capture = load_config(_written(tmp_path, name)).hardware.capture  # type: ignore[union-attr]
    capture = capture.model_copy(update={"n_poses": 1, "burst": BurstConfig(mls_order=9)})
    index = {b.serial: i for i, b in enumerate(capture.boards)}
    mics = [c for c in capture.columns if c.role == "mic"]
    n_cameras = len(capture.cameras)
    layout = ArrayLayout(
        name=name,
        mic_positions_m=0.15 * fibonacci_sphere(len(mics)) + [0.0, 0.0, -0.15],
        mic_normals=fibonacci_sphere(len(mics)),
        cameras=sphere72().cameras[:n_cameras],
        boards=tuple(BoardSpec(b.model, b.serial) for b in capture.boards),
        mic_inputs=tuple(ChannelRef(index[c.board], c.channel) for c in mics),
        speaker_outputs=tuple(ChannelRef(index[s.board], s.output_channel)
                              for s in capture.speakers),
        reference_input=ChannelRef(index[capture.reference.board], capture.reference.channel))
    world = World(layout=layout, rig=Rig(), sample_rate_hz=capture.sample_rate_hz)
    bench = AcousticBench(world)
    cameras = [SimulatedCamera(m, world, i) for i, m in enumerate(layout.cameras)]
    poses = sample_poses(layout.cameras[0], world.rig, 1, (0.6, 0.8), np.random.default_rng(0))
    writer = SessionWriter.create(tmp_path / "session", capture=capture.model_dump(mode="json"))
    group = SyncGroup([SimulatedBoard(spec, bench) for spec in layout.boards])
    CaptureSequencer(capture, group, cameras, SimulatedOperator(
        world, poses, reference_stand_position(layout.cameras[0])), writer).run()
    data = load_session(tmp_path / "session")
    assert data.pose_steps == ("pose/0000",) and len(data.mic_ids) == len(mics)
    recordings = data.pose_recordings("pose/0000")
    assert recordings.shape[:2] == (6, len(capture.columns))
    assert np.all(np.abs(recordings[:, data.mic_columns]).max(axis=2) > 10)  # every mic hears


def test_the_audio_templates_name_their_interfaces(tmp_path: Path) -> None:
    """`audio`: one 16-input interface, 15 microphones and the reference, the speakers on its
    outputs; `uma16`: the array's 16 microphones and an interface for the reference and the
    speakers, which needs one word clock (and says where the geometry comes from)."""
    hw = load_config(_written(tmp_path, "audio")).hardware
    assert hw is not None and hw.backend == "audio" and hw.audio is not None
    assert [d.label for d in hw.audio.devices] == ["interface"] and not hw.audio.word_clock
    capture = hw.capture
    assert sum(c.role == "mic" for c in capture.columns) == 15
    assert (capture.reference.board, capture.reference.channel) == ("interface", 15)
    assert {s.board for s in capture.speakers} == {"interface"}
    assert capture.burst.post_samples > 2048  # the interface's latency comes first
    text = template("uma16")
    hw = load_config(_written(tmp_path, "uma16")).hardware
    assert hw is not None and hw.audio is not None and hw.audio.word_clock
    assert [d.label for d in hw.audio.devices] == ["uma16", "interface"]
    assert [c.mic_id for c in hw.capture.columns if c.board == "uma16"] == list(range(16))
    assert hw.capture.sample_rate_hz == 48_000.0
    assert "acoular/xml/minidsp_uma-16.xml" in text and "ch 15: (-21, -63)" in text
