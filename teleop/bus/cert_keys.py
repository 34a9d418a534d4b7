"""The keys in a CURVE certificate file, checked: Z85 form, who may read a secret one, and that a
secret key is the one its public key comes from (file layout: :mod:`teleop.bus.security`)."""

from __future__ import annotations

import stat
from pathlib import Path

import zmq
from zmq.utils import z85

from teleop.bus import cert_access
from teleop.bus.cert_access import load_certificate
from teleop.errors import BusSecurityError

__all__ = ["PUBLIC_SUFFIX", "SECRET_SUFFIX", "check_z85", "read_public_cert", "read_secret_cert"]

PUBLIC_SUFFIX = ".key"
SECRET_SUFFIX = ".key_secret"
_Z85_KEY_CHARS = 40
# A secret certificate whose secret key does not give its public key: no keys command rewrites one
# (keys are never overwritten), so the pair comes again from where it was made, or is made anew.
_REMAKE_PAIR = ("copy the pair (.key and .key_secret) again from the host that made it, or make new keys "
                "with `teleop keys init NEWDIR` (`teleop keys --help`)")


def check_z85(key: bytes, path: Path, which: str) -> bytes:
    """``key`` when it is a 40-character Z85 CURVE key; else BusSecurityError naming ``path``."""
    try:
        valid = len(key) == _Z85_KEY_CHARS and len(z85.decode(key)) == 32
    except (ValueError, KeyError, TypeError):
        valid = False
    if not valid:
        raise BusSecurityError(f"{path}: the {which} key is not a 40-character Z85 CURVE key")
    return key


def read_public_cert(path: Path, *, in_place: bool = True) -> bytes:
    """A public certificate's key; refuses a secret one, or one used ``in_place`` that others may write."""
    public, secret = load_certificate(path, "CURVE certificate")
    if in_place:
        cert_access.check_owner_writes(path, "CURVE certificate")
    if secret is not None:
        raise BusSecurityError(
            f"{path} holds a secret key: pass the public certificate (.key), never the .key_secret"
        )
    return check_z85(public, path, "public")


def read_secret_cert(path: Path, public_key: bytes) -> bytes:
    """The secret key of ``path``, after checking this user or root owns it, only its owner can read it
    and it yields ``public_key``."""
    public, secret = load_certificate(path, "CURVE secret certificate")
    try:
        info = path.stat()
    except OSError as exc:
        raise BusSecurityError(f"cannot read CURVE secret certificate {path}: {exc}") from exc
    cert_access.check_owner(path, "CURVE secret certificate", info.st_uid)
    mode = stat.S_IMODE(info.st_mode)
    if mode & 0o077:
        raise BusSecurityError(
            f"{path} is readable by other users (mode {mode:04o}): run chmod 600 {path}"
        )
    if secret is None:
        raise BusSecurityError(f"{path} holds no secret key")
    if public != public_key:
        raise BusSecurityError(f"{path} does not belong to {path.with_suffix(PUBLIC_SUFFIX)}")
    check_z85(secret, path, "secret")
    # its public-key line is only a copy: a changed character of the secret key, or another pair's
    # secret, would pass the checks above and fail every handshake without a word
    if zmq.curve_public(secret) != public:
        raise BusSecurityError(
            f"{path}: its secret key does not match its public key (damaged, or from another pair): {_REMAKE_PAIR}"
        )
    return secret
