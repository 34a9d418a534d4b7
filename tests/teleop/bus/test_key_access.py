"""Certificates and keys folders this user may not read, or that are missing: said as such, not as
invalid certificates (:mod:`teleop.bus.cert_access`)."""

from __future__ import annotations

import builtins
import errno
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

import teleop
from teleop.bus.cert_access import access_error, check_owner_writes
from teleop.bus.security import (
    BusSecurity,
    authorize_key,
    init_keys,
    list_keys,
    read_authorized,
    security_from_settings,
)
from teleop.errors import BusSecurityError
from teleop.settings import BusSettings


def _unsearchable(monkeypatch, folder: Path) -> None:
    """Make ``folder`` behave as a directory this user may not search (mode 0700, another
    owner): what lies inside can neither be stat'ed nor opened. Simulated, as root ignores
    permission bits."""
    inside = str(folder.absolute()) + os.sep

    def refused(path) -> bool:
        return isinstance(path, (str, os.PathLike)) and os.path.abspath(os.fspath(path)).startswith(inside)

    real_stat, real_open = os.stat, builtins.open

    def stat_(path, *args, **kwargs):
        if refused(path):
            raise PermissionError(errno.EACCES, "Permission denied", os.fspath(path))
        return real_stat(path, *args, **kwargs)

    def open_(path, *args, **kwargs):
        if refused(path):
            raise PermissionError(errno.EACCES, "Permission denied", os.fspath(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "stat", stat_)
    monkeypatch.setattr(builtins, "open", open_)


def _says_permission(message: str, path: Path) -> None:
    assert "Invalid certificate file" not in message
    assert f"cannot read CURVE certificate {path}: permission denied" in message
    assert "run as the user that owns the keys" in message and "or let " in message


def test_keys_this_user_may_not_read_are_called_unreadable_not_invalid(tmp_path, keys, stranger, monkeypatch):
    # pyzmq calls a certificate it cannot see "Invalid certificate file"
    settings = BusSettings(robot_pub="tcp://*:5550", keys_dir=str(keys.keys_dir))
    _unsearchable(monkeypatch, keys.keys_dir)
    for read in (
        lambda: list_keys(keys.keys_dir),  # teleop keys list
        lambda: authorize_key(keys.keys_dir, stranger.keys_dir / "client.key", name="op"),  # keys add
        lambda: security_from_settings(settings),  # every service started with bus.keys_dir
    ):
        with pytest.raises(BusSecurityError) as info:
            read()
        _says_permission(str(info.value), keys.keys_dir / "server.key")
    monkeypatch.undo()
    _unsearchable(monkeypatch, stranger.keys_dir)  # keys add CERT: the certificate to admit
    with pytest.raises(BusSecurityError) as info:
        authorize_key(keys.keys_dir, stranger.keys_dir / "client.key", name="op")
    _says_permission(str(info.value), stranger.keys_dir / "client.key")


def test_a_keys_folder_inside_one_this_user_cannot_search_is_called_unreadable_not_missing(tmp_path, monkeypatch):
    init_keys(tmp_path / "outer" / "keys")
    _unsearchable(monkeypatch, tmp_path / "outer")  # the keys folder itself cannot be stat'ed
    with pytest.raises(BusSecurityError) as refused:
        BusSecurity.load(tmp_path / "outer" / "keys")
    assert "permission denied" in str(refused.value) and "does not exist" not in str(refused.value), refused.value


def test_a_missing_certificate_is_called_missing(tmp_path, keys):
    absent = tmp_path / "absent.key"
    with pytest.raises(BusSecurityError, match=f"cannot read CURVE certificate {absent}: it does not exist"):
        authorize_key(keys.keys_dir, absent)
    (keys.keys_dir / "client.key").unlink()
    with pytest.raises(BusSecurityError, match="client.key: it does not exist"):
        BusSecurity.load(keys.keys_dir)


@pytest.mark.skipif(
    not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("setpriv") is None,
    reason="runs `teleop keys` as another user: needs root and setpriv",
)
def test_keys_command_as_another_user_says_permission_denied_naming_the_folder_it_cannot_search():
    outer = Path(tempfile.mkdtemp(prefix="teleop-keys-"))
    try:
        # as many home folders: others may pass through it, not list it; the keys folder inside stays
        # 0700, owned by root, and is the one that blocks
        outer.chmod(0o711)
        init_keys(outer / "k1")
        # this checkout's teleop, whichever one the venv's console script would import
        env = {**os.environ, "PYTHONPATH": str(Path(teleop.__file__).parents[1])}
        result = subprocess.run(
            ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable, "-c",
             "import sys; from teleop.cli import main; sys.argv[0] = 'teleop'; sys.exit(main())",
             "keys", "list", str(outer / "k1")],
            capture_output=True, text=True, timeout=60, env=env,
        )
    finally:
        shutil.rmtree(outer)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    _says_permission(result.stderr, outer / "k1" / "server.key")
    assert f"folder {outer / 'k1'} (owner root, mode 0700)" in result.stderr


def test_a_dangling_key_in_the_authorised_folder_is_to_be_removed(keys, tmp_path):
    (keys.keys_dir / "authorized" / "gone.key").symlink_to(tmp_path / "nowhere.key")
    with pytest.raises(BusSecurityError, match="it does not exist: remove it from"):
        list_keys(keys.keys_dir)


def test_permission_denied_names_the_outermost_folder_this_user_cannot_search(tmp_path, monkeypatch):
    # outer/ and outer/inner/ both closed: only opening outer/ helps first, so it is the one named
    outer = tmp_path / "outer"
    (outer / "inner" / "keys").mkdir(parents=True)
    closed, real_access = str(outer.absolute()), os.access
    monkeypatch.setattr(os, "access", lambda p, mode, *a, **k: False if os.fspath(p).startswith(closed)
                        else real_access(p, mode, *a, **k))
    error = access_error(outer / "inner" / "keys" / "server.key", "CURVE certificate",
                         PermissionError(errno.EACCES, "Permission denied"))
    assert f"folder {outer} (owner " in str(error) and "let " in str(error) and f"read {outer}" in str(error)


def test_a_missing_keys_folder_is_said_to_be_missing_with_how_to_make_one(tmp_path):
    with pytest.raises(BusSecurityError, match=r"CURVE keys directory .*absent does not exist: run `teleop keys init DIR`"):
        BusSecurity.load(tmp_path / "absent")
    init_keys(tmp_path / "keys")
    shutil.rmtree(tmp_path / "keys" / "authorized")
    with pytest.raises(BusSecurityError, match=r"authorised-keys directory .* does not exist: run `teleop keys init`"):
        read_authorized(tmp_path / "keys" / "authorized")


def test_the_owner_write_check_refuses_a_path_it_cannot_inspect(tmp_path):
    # fail closed: a folder or certificate whose owner and mode cannot be read is not taken as safe
    with pytest.raises(BusSecurityError, match="does not exist"):
        check_owner_writes(tmp_path / "absent", "CURVE keys directory")
