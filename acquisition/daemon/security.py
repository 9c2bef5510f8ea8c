"""The daemon side of security: refuse an exposed bind without CURVE, run the CURVE server.

A loopback TCP address or an ipc socket is reachable only from this machine (and, for ipc, only
by users the file permissions let in). Any other bind exposes the daemon's control of the
hardware to the network, so the daemon refuses it unless CURVE is configured: traffic is then
encrypted, and only clients whose public key is in the authorised directory get an answer.
"""

from __future__ import annotations

import zmq
from zmq.auth.thread import ThreadAuthenticator

from .config import ConfigError, CurveConfig, SocketsConfig
from .endpoints import is_local_endpoint
from .keys import load_certificate


def check_exposure(sockets: SocketsConfig) -> None:
    """Refuse a non-local bind without CURVE (ConfigError says what to do)."""
    endpoints = (sockets.control, sockets.events, sockets.jobs_endpoint, sockets.files_endpoint)
    exposed = [e for e in endpoints if not is_local_endpoint(e)]
    if exposed and sockets.curve is None:
        raise ConfigError(
            f"refusing to bind {', '.join(exposed)} without encryption: a non-loopback address "
            "needs CURVE keys. Create them with `micam daemon --make-keys DIR`, then set "
            "[sockets.curve] server_secret_key and authorized_clients in the config, or bind "
            "tcp://127.0.0.1:PORT or ipc://PATH instead")


class CurveServer:
    """Starts the authenticator thread and makes server sockets CURVE servers."""

    def __init__(self, context: zmq.Context, curve: CurveConfig) -> None:
        if not curve.authorized_clients.is_dir():
            raise ConfigError(f"authorized_clients {curve.authorized_clients} is not a directory "
                              "of client public keys")
        self._public, self._secret = load_certificate(curve.server_secret_key, secret=True)
        self._auth = ThreadAuthenticator(context)
        self._auth.start()
        self._auth.configure_curve(domain="*", location=str(curve.authorized_clients))

    def secure(self, sock: zmq.Socket) -> None:
        """Make `sock` a CURVE server (call before bind)."""
        sock.curve_secretkey = self._secret
        sock.curve_publickey = self._public
        sock.curve_server = True

    def stop(self) -> None:
        self._auth.stop()
