"""Under JACK, whether a device is still there: PortAudio does not say.

A JACK "device" is a client's set of ports (the server's own, "system", or a program's). When
that client quits, PortAudio's stream runs on, reading silence; when the server goes away,
the stream stops. `JackWatch` is a client of its own (no ports) that the server tells when a
client leaves or when it shuts down (JACK-Client's notification callbacks, on a thread of
their own); the stream asks it on every read. Without the JACK-Client package nothing is
watched (docs/hardware.md says what is then not detected).
"""

from __future__ import annotations

import os
from itertools import count

_names = count()


class JackWatch:
    """Watches the JACK client `device` (module docstring); `gone` says why it is gone."""

    def __init__(self, device: str) -> None:
        self.device = device
        self.gone: str | None = None
        self._server_down = False
        self._client = None
        try:
            import jack
        except (ImportError, OSError):  # not installed: nothing is watched
            return
        try:
            client = jack.Client(f"micam-watch-{os.getpid()}-{next(_names)}",
                                 no_start_server=True)
        except jack.JackError:  # no server: the stream's own start fails and says so
            return
        client.set_client_registration_callback(self._registration)
        client.set_shutdown_callback(self._shutdown)
        client.activate()
        self._client = client

    @property
    def watching(self) -> bool:
        return self._client is not None

    def _registration(self, name: str, register: bool) -> None:
        if not register and name == self.device:
            self.gone = f"its JACK client {name!r} left the server (the program quit)"

    def _shutdown(self, status: object, reason: str) -> None:
        self._server_down = True
        self.gone = f"the JACK server shut down ({reason.strip() or 'no reason given'})"

    def close(self) -> None:
        """Leave the server (not after it shut down: there is nothing to leave)."""
        client, self._client = self._client, None
        if client is None or self._server_down:
            return
        try:
            client.deactivate()
            client.close()
        except Exception:  # the server went down meanwhile
            pass
