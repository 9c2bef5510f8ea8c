"""Who on this machine may drive the daemon: its ipc sockets are files with a mode it sets, in a
runtime directory it makes 0750; abstract sockets and loopback TCP need CURVE (or an explicit
opt-in); secret keys are private."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

from acquisition.daemon.config import ConfigError, SocketsConfig
from acquisition.daemon.endpoints import beside
from acquisition.contracts.keys import load_certificate, make_keys
from acquisition.daemon.security import check_exposure
from acquisition.contracts.errors import UserError

from .helpers import ThreadDaemon, small_config


def _mode(path: Path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.fixture
def permissive_umask() -> Iterator[None]:
    """umask 0: whatever the daemon does not set itself would be open to everyone."""
    old = os.umask(0)
    yield
    os.umask(old)


def test_the_default_sockets_are_ipc_in_a_0750_runtime_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, permissive_umask: None) -> None:
    runtime = tmp_path / "run" / "micam"
    monkeypatch.setenv("MICAM_RUNTIME_DIR", str(runtime))
    sockets = SocketsConfig()
    assert sockets.control == f"ipc://{runtime}/control"
    running = ThreadDaemon(small_config(tmp_path, sockets=sockets))
    try:
        with running.client() as client:
            assert client.request("ping")["pong"]
        assert _mode(runtime) == 0o750
        control = f"{runtime}/control"
        for path in (control, f"{runtime}/events", f"{control}-jobs", f"{control}-files"):
            assert stat.S_ISSOCK(os.stat(path).st_mode) and _mode(Path(path)) == 0o660, path
    finally:
        running.stop()
    assert beside(sockets.control, "jobs") == f"ipc://{control}-jobs"


def test_an_ipc_socket_where_others_can_reach_it_is_refused(tmp_path: Path) -> None:
    open_dir = tmp_path / "open"
    open_dir.mkdir()
    open_dir.chmod(0o755)
    sockets = SocketsConfig(control=f"ipc://{open_dir}/control",
                            events=f"ipc://{tmp_path}/events")
    with pytest.raises(ConfigError, match="other users could reach or replace it"):
        ThreadDaemon(small_config(tmp_path, sockets=sockets))


@pytest.mark.parametrize(("control", "words"), [
    ("ipc://@micam-control", "abstract ipc socket has no permissions"),
    ("tcp://127.0.0.1:5560", "every account on this machine"),
])
def test_sockets_without_permissions_need_curve(tmp_path: Path, control: str,
                                                words: str) -> None:
    sockets = SocketsConfig(control=control, events=f"ipc://{tmp_path}/events")
    with pytest.raises(ConfigError, match=words):
        check_exposure(sockets)


def test_loopback_tcp_can_be_allowed_explicitly(tmp_path: Path) -> None:
    check_exposure(SocketsConfig(control="tcp://127.0.0.1:5560", events="tcp://127.0.0.1:5561",
                                 allow_tcp_loopback=True))


def test_secret_keys_are_written_private_and_refused_when_readable(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        made = make_keys(tmp_path / "keys")
    finally:
        os.umask(old)
    secrets = [p for p in made if p.name.endswith("_secret")]
    assert len(secrets) == 2 and all(_mode(p) == 0o600 for p in secrets)
    assert all(_mode(p) == 0o644 for p in made if p not in secrets)
    secret = secrets[0]
    load_certificate(secret, secret=True)
    secret.chmod(0o640)
    with pytest.raises(UserError, match=r"other users may read it.*chmod 600"):
        load_certificate(secret, secret=True)
    load_certificate(secret.with_name(secret.name.removesuffix("_secret")), secret=False)
