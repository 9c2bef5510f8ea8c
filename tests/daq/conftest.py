"""Fixtures of the driver layer's tests: one JACK server for the audio backend's tests and the
board conformance test (tests/daq/test_board_conformance.py).

The server is started once for every module that asks for it (its name is private to this
run); the process's PortAudio is initialised against it and terminated before it stops, so
that nothing in this process holds a stream of a server that is gone.
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from .audio.jack_helpers import JackServer, require_audio_stack


@pytest.fixture(scope="package")
def jack_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[JackServer]:
    require_audio_stack()
    import sounddevice

    server = JackServer(f"micam-test-{os.getpid()}", tmp_path_factory.mktemp("jack"))
    saved = {k: os.environ.get(k) for k in ("JACK_DEFAULT_SERVER", "JACK_NO_AUDIO_RESERVATION",
                                            "JACK_NO_START_SERVER")}
    os.environ.update({k: server.env[k] for k in saved})
    sounddevice._terminate()
    sounddevice._initialize()  # PortAudio finds this server
    yield server
    sounddevice._terminate()
    server.stop()
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    sounddevice._initialize()
