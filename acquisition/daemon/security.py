"""The daemon side of security: refuse an exposed bind without CURVE, run the CURVE server.

An ipc socket file is reachable only by the users its permissions let in (local_access.py
sets them). Everything else is refused unless CURVE is configured, so that only clients whose
public key is in the authorised directory get an answer (traffic is then also encrypted):

- any bind that the network may reach (`tcp://*`, an interface, a LAN address);
- an abstract ipc socket (`ipc://@name`): no file, so no permissions, any local user;
- loopback TCP (`tcp://127.0.0.1`): any local account, unless `allow_tcp_loopback` says that
  is intended.

docs/security.md says what is trusted and how to let other users in safely.
"""

from __future__ import annotations

import zmq
from zmq.auth.thread import ThreadAuthenticator

from .config import ConfigError, CurveConfig, SocketsConfig
from .endpoints import is_abstract_ipc, is_local_endpoint, is_tcp
from acquisition.contracts.keys import load_certificate


def check_exposure(sockets: SocketsConfig) -> None:
    """Refuse a bind that strangers could reach without CURVE (ConfigError says what to do)."""
    if sockets.curve is not None:
        return
    endpoints = (sockets.control, sockets.events, sockets.jobs_endpoint, sockets.files_endpoint)
    keys = ("Create keys with `micam daemon --make-keys DIR`, then set [sockets.curve] "
            "server_secret_key and authorized_clients in the config")
    exposed = [e for e in endpoints if not is_local_endpoint(e)]
    if exposed:
        raise ConfigError(
            f"refusing to bind {', '.join(exposed)} without encryption: a non-loopback address "
            f"needs CURVE keys. {keys}, or bind ipc://PATH instead")
    abstract = [e for e in endpoints if is_abstract_ipc(e)]
    if abstract:
        raise ConfigError(
            f"refusing to bind {', '.join(abstract)} without CURVE: an abstract ipc socket has "
            f"no permissions, so every local user could drive the daemon. {keys}, or use an "
            "ipc socket file (ipc:///run/micam/control)")
    loopback = [e for e in endpoints if is_tcp(e)]
    if loopback and not sockets.allow_tcp_loopback:
        raise ConfigError(
            f"refusing to bind {', '.join(loopback)} without CURVE: every account on this "
            "machine can connect to loopback TCP. Use the default ipc sockets (only the "
            f"daemon's user and group), or CURVE ({keys}), or set [sockets] "
            "allow_tcp_loopback = true if every local user may drive the daemon")


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
