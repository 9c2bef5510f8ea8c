"""CURVE key files: making them, reading them, and making a client socket use them.

Key files are ZeroMQ certificates (`zmq.auth.create_certificates`): `NAME.key` holds the public
key, `NAME.key_secret` the public and the secret key. A secret key is written with mode 0600
and refused when any other user may read it (as ssh refuses a private key): whoever reads it
can pose as its owner. This module is shared by the daemon and the client, so it imports
nothing heavy.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import zmq
import zmq.auth

from acquisition.contracts.errors import UserError


def load_certificate(path: Path, secret: bool) -> tuple[bytes, bytes | None]:
    """(public key, secret key or None) from a certificate file; UserError if unusable, or if
    `secret` and other users may read the file."""
    try:
        public, secret_key = zmq.auth.load_certificate(str(path))
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except (OSError, ValueError) as exc:
        raise UserError(f"cannot read the ZeroMQ certificate {path}: {exc}") from None
    if secret and not secret_key:
        raise UserError(f"{path} holds no secret key; use the *.key_secret file")
    if secret and mode & 0o077:
        raise UserError(f"{path} holds a secret key but other users may read it (mode "
                        f"{mode:04o}): whoever reads it can pose as its owner. Make it private "
                        f"with `chmod 600 {path}` (and consider making new keys)")
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
    umask = os.umask(0o077)  # the secret files are created private, never readable meanwhile
    try:
        for name in ("server", "client"):
            public, secret = zmq.auth.create_certificates(str(directory), name)
            made += [Path(public), Path(secret)]
    finally:
        os.umask(umask)
    for path in made:  # public keys are for sharing; secret ones stay 0600
        os.chmod(path, 0o600 if path.name.endswith("_secret") else 0o644)
    (authorized / "client.key").write_bytes((directory / "client.key").read_bytes())
    return [*made, authorized / "client.key"]
