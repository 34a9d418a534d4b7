"""Reading CURVE certificates and keys folders, with the operating system's reason when one cannot be.

A keys folder, its ``authorized/`` folder and a public certificate used in place must be owned by this
user or root and writable by their owner alone (:func:`check_owner_writes`): another local user who may
write them could authorise their own key or swap the server's public key, as ssh (StrictModes) refuses
such files. A secret certificate another user owns is refused too (:func:`check_owner`).

pyzmq calls a certificate it cannot see (missing, or in a folder this user may not search) an
"Invalid certificate file"; these open it first, so a permission problem is said as one, naming
the folder or file that blocks it, its owner and what to do (:mod:`teleop.bus.security`).
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
from pathlib import Path

import zmq.auth

from teleop.errors import BusSecurityError

__all__ = [
    "CertificateAccessError",
    "access_error",
    "check_owner",
    "check_owner_writes",
    "copy_public",
    "is_dir",
    "load_certificate",
]

PUBLIC_MODE = 0o644  # a public certificate: anyone may read it, its owner alone write it


class CertificateAccessError(BusSecurityError):
    """A certificate or keys folder this process may not read, or others may write or own (its
    permissions, not its contents)."""


def _user_name(uid: int) -> str:
    try:
        import pwd

        return pwd.getpwuid(uid).pw_name
    except (ImportError, KeyError):
        return f"uid {uid}"


def access_error(path: Path, what: str, exc: OSError) -> BusSecurityError:
    """Why ``path`` cannot be opened, in words: missing, or not readable by this user."""
    if exc.errno in (errno.ENOENT, errno.ENOTDIR):
        return BusSecurityError(f"cannot read {what} {path}: it does not exist")  # a dangling link: remove it
    if exc.errno not in (errno.EACCES, errno.EPERM):
        return BusSecurityError(f"cannot read {what} {path}: {exc}")
    user = _user_name(os.geteuid()) if hasattr(os, "geteuid") else "this user"
    blocked, kind = path, "file"
    for folder in reversed(path.absolute().parents):  # the first folder we may not search
        if not os.access(folder, os.X_OK):
            blocked, kind = folder, "folder"
            break
    try:
        info = os.stat(blocked)
        owner = _user_name(info.st_uid)
        detail = (f"{kind} {blocked} (owner {owner}, mode {stat.S_IMODE(info.st_mode):04o}) "
                  f"is not readable by {user}")
        fix = f"run as the user that owns the keys ({owner}), or let {user} read {blocked}"
    except OSError:
        detail = f"{path} or a folder above it is not readable by {user}"
        fix = f"run as the user that owns the keys, or let {user} read it"
    return CertificateAccessError(
        f"cannot read {what} {path}: permission denied: {detail}: {fix}"
    )


def load_certificate(path: Path, what: str) -> tuple[bytes, bytes | None]:
    """``zmq.auth.load_certificate``, saying why a file that cannot be opened cannot be."""
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise access_error(path, what, exc) from exc
    try:
        return zmq.auth.load_certificate(path)
    except (OSError, ValueError) as exc:
        raise BusSecurityError(f"cannot read {what} {path}: {exc}") from exc


def is_dir(path: Path, what: str) -> bool:
    """Whether ``path`` is a directory (False: missing); refuses one this user cannot reach."""
    try:
        return stat.S_ISDIR(os.stat(path).st_mode)
    except OSError as exc:
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            return False
        raise access_error(path, what, exc) from exc


def _described_uid(uid: int) -> str:
    """``uid 1000 (alice)``, or ``uid 1000`` for a uid without a name."""
    name = _user_name(uid)
    return f"uid {uid}" if name == f"uid {uid}" else f"uid {uid} ({name})"


def check_owner(path: Path, what: str, owner_uid: int) -> None:
    """Refuse ``path``, owned by ``owner_uid``, unless this user or root owns it: its owner may change
    it, and its mode, whatever the mode is now."""
    if not hasattr(os, "geteuid"):  # no POSIX owners to compare
        return
    user_uid = os.geteuid()
    if owner_uid not in (user_uid, 0):
        raise CertificateAccessError(
            f"{what} {path} is owned by {_described_uid(owner_uid)}: expected uid {user_uid} (this user) or "
            f"root, as its owner may rewrite it (or read it) whatever its mode; run as its owner, or have root "
            f"run chown {user_uid} {path}"
        )


def check_owner_writes(path: Path, what: str) -> None:
    """Refuse ``path`` when a user other than this one or root owns it, or its group or other users may
    write it, naming the chown or chmod that fixes it."""
    try:
        info = os.stat(path)
    except OSError as exc:
        raise access_error(path, what, exc) from exc
    check_owner(path, what, info.st_uid)
    mode = stat.S_IMODE(info.st_mode)
    if mode & 0o022:
        raise CertificateAccessError(
            f"{what} {path} is writable by other users (mode {mode:04o}): any of them could authorise their "
            f"own key or replace a public key; run chmod go-w {path}"
        )


def make_private_dir(directory: Path) -> None:
    """Create ``directory`` (mode 0700), or take group's and others' write bits off one that exists
    (``mkdir ~/keys`` under a 002 umask makes it 0775): :func:`check_owner_writes` refuses it else;
    one another user owns is refused (:func:`check_owner`), as it would be when read."""
    directory.mkdir(mode=0o700, parents=True, exist_ok=True)
    info = os.stat(directory)
    check_owner(directory, "CURVE keys directory", info.st_uid)
    os.chmod(directory, stat.S_IMODE(info.st_mode) & ~0o022)


def copy_public(source: Path | str, target: Path) -> None:
    """Copy a public certificate to ``target``, writable by its owner alone whatever the umask."""
    shutil.copyfile(source, target)
    os.chmod(target, PUBLIC_MODE)
