"""Unit tests of the configuration: TOML, environment overrides, clear errors, exposure."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from acquisition.contracts.burst import MAX_PERIODS
from acquisition.contracts.config_model import models_within
from acquisition.daemon.config import ConfigError, SocketsConfig
from micam.hardware import load_daemon_config as load_config
from micam.simulated_hardware import MicamDaemonConfig as DaemonConfig
from acquisition.daemon.endpoints import is_local_endpoint
from acquisition.daemon.security import check_exposure
from kernel.stimulus import MAX_MLS_ORDER


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "daemon.toml"
    path.write_text(text)
    return path


def test_toml_then_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = _write(tmp_path, 'session_root = "/data/s"\n[sockets]\ncontrol = "ipc:///run/c"\n'
                            '[simulation]\narray = "scatter48"\nposes = 4\n'
                            '[quality]\nsnr = "warn"\n')
    monkeypatch.setenv("MICAM_DAEMON_SOCKETS__CONTROL", "ipc:///run/other")
    monkeypatch.setenv("MICAM_DAEMON_QUALITY__AUTO_RETRIES", "3")
    config = load_config(path)
    assert isinstance(config, DaemonConfig)  # the simulated world's, with its [simulation]
    assert config.session_root == Path("/data/s")
    assert config.sockets.control == "ipc:///run/other"  # the environment wins
    assert config.simulation.poses == 4 and config.simulation.array == "scatter48"
    assert config.quality.snr == "warn" and config.quality.auto_retries == 3
    assert config.simulated


def test_defaults_without_a_file() -> None:
    config = load_config(None)
    assert is_local_endpoint(config.sockets.control) and is_local_endpoint(config.sockets.events)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("poll_interval = 1\n", "poll_interval: unknown key 'poll_interval' at the top level"),
        ("[simulation]\narray = \"cube\"\n", "unknown array 'cube'"),
        ("[simulation]\nbogus = 1\n", "simulation.bogus"),
        ("[quality]\nclipping = \"maybe\"\n", "quality.clipping"),
        ("[sockets]\nmax_message_bytes = 10\n", "sockets.max_message_bytes"),
        ("session_root = [\n", "not valid TOML"),
        ("[hardware]\ncameras = []\n", "hardware.capture: Field required"),
    ],
)
def test_invalid_configs_name_the_problem(tmp_path: Path, text: str, words: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=str(path)) as caught:
        load_config(path)
    assert words in str(caught.value)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.toml")


@pytest.mark.parametrize(
    ("endpoint", "local"),
    [("tcp://127.0.0.1:5560", True), ("tcp://127.1.2.3:1", True), ("tcp://[::1]:5560", True),
     ("tcp://localhost:1", True), ("ipc:///run/micam/control", True), ("inproc://x", True),
     ("tcp://*:5560", False), ("tcp://0.0.0.0:5560", False), ("tcp://eth0:5560", False),
     ("tcp://192.168.1.5:5560", False), ("tcp://[::]:1", False), ("udp://127.0.0.1:1", False),
     ("nonsense", False)],
)
def test_local_endpoints(endpoint: str, local: bool) -> None:
    assert is_local_endpoint(endpoint) is local


def test_non_loopback_bind_needs_curve() -> None:
    with pytest.raises(ConfigError, match=r"refusing to bind tcp://\*:5560.*CURVE"):
        check_exposure(SocketsConfig(control="tcp://*:5560"))
    check_exposure(SocketsConfig())  # loopback: fine


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()
                               if v is not None) + "}"
    return repr(value)


def _toml_table(doc: dict[str, Any], name: str, header: str = "") -> str:
    """`doc` as TOML the way a person writes it: [tables], [[arrays of tables]] of nested
    entries, and arrays of inline tables for flat ones (channel lists)."""
    lines = [header or f"[{name}]"]
    subtables = []
    for key, value in doc.items():
        if isinstance(value, dict):
            subtables.append(_toml_table(value, f"{name}.{key}"))
        elif (isinstance(value, list) and value and all(isinstance(v, dict) for v in value)
              and any(isinstance(x, dict | list) for v in value for x in v.values())):
            subtables += [_toml_table(v, f"{name}.{key}", f"[[{name}.{key}]]") for v in value]
        elif value is not None:
            lines.append(f"{key} = {_toml_value(value)}")
    return "\n".join(lines) + "\n\n" + "".join(subtables)


@pytest.fixture(scope="module")
def hardware_toml() -> str:
    """A valid [hardware] section: the small simulated rig's capture configuration as TOML."""
    from sim.capture import SimulationOptions, build_simulated_capture

    capture = build_simulated_capture(
        SimulationOptions(array="scatter48", poses=2, mls_order=9, seed=3)).config
    cameras = [{"name": c.name, "device": f"/dev/video{i}", "width": 1280, "height": 960}
               for i, c in enumerate(capture.cameras)]
    doc = {"firmware_dir": "/opt/micam/firmware", "capture": capture.model_dump(mode="json"),
           "cameras": cameras}
    return _toml_table(doc, "hardware")


def test_a_hand_written_hardware_section_loads(tmp_path: Path, hardware_toml: str) -> None:
    assert "[hardware.capture.burst]" in hardware_toml  # written as sections, as people do
    assert "[[hardware.capture.boards]]" in hardware_toml
    config = load_config(_write(tmp_path, hardware_toml))
    assert config.hardware is not None and not config.simulated
    assert config.hardware.capture.burst.mls_order == 9
    assert [c.name for c in config.hardware.cameras] == ["cam0"]


@pytest.mark.parametrize(
    ("good", "bad", "where", "hint"),
    [
        ("amplitude_v = ", "burst_amplitud_v = ", "[hardware.capture.burst]", "amplitude_v"),
        ("corners_x = ", "corner_x = ", "[hardware.capture.rig]", "corners_x"),
        ("distance_from_speaker_m = ", "distance_m = ", "[hardware.capture.reference]",
         "distance_from_speaker_m"),
        ("{channel = 0, range_v = ", "{channel = 0, rnage_v = ",
         "[hardware.capture.boards[0].inputs[0]]", "range_v"),
        ('device = "/dev/video0"', 'devise = "/dev/video0"', "[hardware.cameras[0]]", "device"),
        ("sample_rate_hz = ", "sample_rate = ", "[hardware.capture]", "sample_rate_hz"),
        ('firmware_dir = "', 'firmware = "', "[hardware]", "firmware_dir"),
    ],
)
def test_a_misspelt_hardware_key_is_named_with_its_section(
        tmp_path: Path, hardware_toml: str, good: str, bad: str, where: str, hint: str) -> None:
    text = hardware_toml.replace(good, bad, 1)
    assert text != hardware_toml
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    message = str(caught.value)
    key = bad.removeprefix("{channel = 0, ").split(" = ")[0]
    (line,) = [ln for ln in message.splitlines() if f"unknown key {key!r}" in ln]
    assert f"in {where}" in line and f"did you mean {hint!r}" in line
    assert "it accepts: " in line and hint in line.split("it accepts: ")[1]
    assert str(path) in message and "docs/protocol.md" in message
    assert "Traceback" not in message and "pydantic" not in message


def test_a_camera_s_pixel_format_is_one_micam_decodes(tmp_path: Path,
                                                      hardware_toml: str) -> None:
    text = hardware_toml.replace('height = 960', 'height = 960, fourcc = "YUYV"', 1)
    config = load_config(_write(tmp_path, text))
    assert config.hardware is not None and config.hardware.cameras[0].fourcc == "YUYV"
    with pytest.raises(ConfigError) as caught:
        load_config(_write(tmp_path, text.replace('"YUYV"', '"MJPEG"')))
    (line,) = [ln for ln in str(caught.value).splitlines() if "fourcc" in ln]
    assert line.startswith("  hardware.cameras[0].fourcc: Input should be 'MJPG' or 'YUYV'"), line


@pytest.mark.parametrize(("good", "bad", "field", "bound"), [
    ("mls_order = 9", "mls_order = 30", "hardware.capture.burst.mls_order", MAX_MLS_ORDER),
    ("periods = 1", "periods = 9", "hardware.capture.burst.periods", MAX_PERIODS),
    ("", "[simulation]\nmls_order = 30", "simulation.mls_order", MAX_MLS_ORDER),
    ("", "[simulation]\nmls_periods = 9", "simulation.mls_periods", MAX_PERIODS),
])
def test_a_burst_beyond_its_bounds_is_one_line_naming_the_field(
        tmp_path: Path, hardware_toml: str, good: str, bad: str, field: str, bound: int) -> None:
    """The burst's bounds (acquisition/contracts/burst.py) reach a daemon's configuration,
    hardware or simulated, as one line that names the key and the bound."""
    text = hardware_toml.replace(good, bad, 1) if good else bad + "\n"
    assert text != hardware_toml
    with pytest.raises(ConfigError) as caught:
        load_config(_write(tmp_path, text))
    problems = [ln for ln in str(caught.value).splitlines() if ln.startswith("  ")]
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"  {field}: Input should be less than or equal to {bound} ")


def test_every_problem_on_its_own_line(tmp_path: Path, hardware_toml: str) -> None:
    text = (hardware_toml.replace("mls_order = ", "mls_ordr = ", 1)
            + '[quality]\nclipping = "maybe"\n')
    with pytest.raises(ConfigError) as caught:
        load_config(_write(tmp_path, text))
    problems = [ln for ln in str(caught.value).splitlines() if ln.startswith("  ")]
    assert len(problems) == 2
    assert any(re.match(r"  hardware\.capture\.burst\.mls_ordr: unknown key", p)
               for p in problems)
    assert any(p.startswith("  quality.clipping: Input should be") and "'maybe'" in p
               for p in problems)


def test_a_misspelt_nested_environment_override_is_refused(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MICAM_DAEMON_QUALITY__AUTO_RETRYS", "2")
    with pytest.raises(ConfigError, match=r"quality\.auto_retrys: unknown key .*auto_retries"):
        load_config(None)


def test_every_configuration_model_refuses_unknown_keys() -> None:
    models = models_within(DaemonConfig)
    names = {m.__name__ for m in models}
    assert {"CaptureConfig", "BurstConfig", "BoardEntry", "InputChannel", "V4L2CameraConfig",
            "CurveConfig", "SimulationConfig"} <= names  # the walk reaches the nested ones
    lenient = [m.__name__ for m in models if m.model_config.get("extra") != "forbid"]
    assert lenient == []


REPO = Path(__file__).resolve().parents[3]


def test_the_documented_examples_and_shipped_files_load(tmp_path: Path) -> None:
    """Every TOML example of the docs, and every TOML file shipped (pyproject.toml aside), is
    a valid configuration (an example with [recordings] a valid import description)."""
    from acquisition.importer import load_spec

    docs = [*REPO.glob("*.md"), *REPO.glob("docs/*.md")]
    blocks = [b for doc in docs
              for b in re.findall(r"```toml\n(.*?)```", doc.read_text(), flags=re.S)]
    assert len(blocks) >= 3  # docs/protocol.md: the daemon's example and [workers]; import.md
    for block in blocks:
        if "[recordings]" in block:
            load_spec(_write(tmp_path, block))
        else:
            load_config(_write(tmp_path, block))
    shipped = [p for p in REPO.rglob("*.toml") if p.name != "pyproject.toml"
               and not {".venv", ".git", "node_modules"} & set(p.relative_to(REPO).parts)]
    for path in shipped:
        load_config(path)
