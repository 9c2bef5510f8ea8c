"""CURVE key files: making them, reading them, and making a client socket use them.

Key files are ZeroMQ certificates (`zmq.auth.create_certificates`): `NAME.key` holds the public
key, `NAME.key_secret` the public and the secret key. This module is shared by the daemon and
the client, so it imports nothing heavy.
"""

from __future__ import annotations

from pathlib import Path

import zmq
import zmq.auth

from ..errors import UserError


def load_certificate(path: Path, secret: bool) -> tuple[bytes, bytes | None]:
    """(public key, secret key or None) from a certificate file; UserError if unusable."""
    try:
        public, secret_key = zmq.auth.load_certificate(str(path))
    except (OSError, ValueError) as exc:
        raise UserError(f"cannot read the ZeroMQ certificate {path}: {exc}") from None
    if secret and not secret_key:
        raise UserError(f"{path} holds no secret key; use the *.key_secret file")
    return public, secret_key


def secure_client(sock: zmq.Socket, server_key: Path, client_key: Path) -> None:
    """Make `sock` a CURVE client of the daemon whose public certificate is `server_key`, with
    the client's own secret certificate `client_key` (call before connect)."""
    server_public, _ = load_certificate(server_key, secret=False)
    public, secret = load_certificate(client_key, secret=True)
    sock.curve_serverkey = server_public
    sock.curve_publickey = public
    sock.curve_secretkey = secret


def make_keys(directory: Path) -> list[Path]:
    """Create a server and a client key pair in `directory`, and an `authorized/` directory
    holding the client's public key (for `authorized_clients`); return the files made."""
    directory = Path(directory)
    authorized = directory / "authorized"
    authorized.mkdir(parents=True, exist_ok=True)
    made = []
    for name in ("server", "client"):
        public, secret = zmq.auth.create_certificates(str(directory), name)
        made += [Path(public), Path(secret)]
    (authorized / "client.key").write_bytes((directory / "client.key").read_bytes())
    return [*made, authorized / "client.key"]
