"""Unit tests of the configuration: TOML, environment overrides, clear errors, exposure."""

from __future__ import annotations

from pathlib import Path

import pytest

from acquisition.daemon.config import ConfigError, SocketsConfig, load_config
from acquisition.daemon.endpoints import is_local_endpoint
from acquisition.daemon.security import check_exposure


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
        ("poll_interval = 1\n", "poll_interval: Extra inputs are not permitted"),
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
