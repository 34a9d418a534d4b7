"""A keys folder, its authorized/ folder or a public certificate that other users may write is refused,
naming the path and the chmod, and so is one owned by a user other than this one or root, naming its
owner (teleop.bus.cert_access.check_owner_writes); so is a secret certificate other users may read or
own, or one whose secret key is no Z85 key (teleop.bus.cert_keys)."""

from __future__ import annotations

import os
import re
import stat

import pytest

from teleop.bus.security import BusSecurity, authorize_key, init_keys, read_authorized
from teleop.errors import BusSecurityError

_SECRET_LINE = re.compile(r'(secret-key = ")([^"]{40})(")')


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.parametrize("relative, mode", [("", 0o770), ("", 0o777), ("server.key", 0o664), ("client.key", 0o646)])
def test_a_keys_folder_or_public_certificate_others_may_write_is_refused(tmp_path, relative, mode):
    init_keys(tmp_path / "keys")
    target = tmp_path / "keys" / relative
    target.chmod(mode)
    with pytest.raises(BusSecurityError, match="writable by other users") as refused:
        BusSecurity.load(tmp_path / "keys")
    assert f"{target} is writable" in str(refused.value).replace(f"{target}/ ", f"{target} ")
    assert f"chmod go-w {target}" in str(refused.value)


@pytest.mark.parametrize("mode", [0o640, 0o620, 0o610, 0o604, 0o602, 0o601])
def test_a_secret_certificate_its_group_or_others_may_use_is_refused(tmp_path, mode):
    # the owner alone: any group or other bit is refused, as ssh refuses a private key
    init_keys(tmp_path / "keys")
    (tmp_path / "keys" / "client.key_secret").chmod(mode)
    with pytest.raises(BusSecurityError, match=f"mode {mode:04o}.*chmod 600"):
        BusSecurity.load(tmp_path / "keys")


@pytest.mark.parametrize("bad", ["x" * 39, "~" * 40])
def test_a_secret_key_that_is_no_z85_key_is_refused_naming_the_file(tmp_path, bad):
    # truncated or garbled: said as such, not a bare ValueError from libzmq
    init_keys(tmp_path / "keys")
    secret = tmp_path / "keys" / "client.key_secret"
    secret.write_text(_SECRET_LINE.sub(lambda m: m.group(1) + bad + m.group(3), secret.read_text()))
    assert secret.stat().st_mode & 0o777 == 0o600  # refused for its key, not its mode
    with pytest.raises(BusSecurityError, match=f"{secret}: the secret key is not a 40-character Z85 CURVE key"):
        BusSecurity.load(tmp_path / "keys")


def test_a_secret_certificate_holding_only_a_public_key_is_said_to_hold_no_secret_key(tmp_path):
    # the usual slip: client.key copied over client.key_secret (mode kept 0600)
    init_keys(tmp_path / "keys")
    secret = tmp_path / "keys" / "client.key_secret"
    secret.write_bytes((tmp_path / "keys" / "client.key").read_bytes())
    assert _mode(secret) == 0o600  # refused for its contents, not its mode
    with pytest.raises(BusSecurityError, match=f"{re.escape(str(secret))} holds no secret key"):
        BusSecurity.load(tmp_path / "keys")


@pytest.mark.parametrize("relative, mode", [("authorized", 0o775), ("authorized/client.key", 0o666)])
def test_an_authorized_folder_or_key_others_may_write_is_refused(tmp_path, relative, mode):
    init_keys(tmp_path / "keys")
    target = tmp_path / "keys" / relative
    target.chmod(mode)
    with pytest.raises(BusSecurityError, match=f"{target} is writable by other users .mode 0{mode:o}.") as refused:
        read_authorized(tmp_path / "keys" / "authorized")
    assert str(refused.value).endswith(f"chmod go-w {target}")


def test_keys_made_and_authorised_under_a_group_umask_are_accepted(tmp_path):
    previous = os.umask(0o002)  # a user-private-group umask: files come out group-writable
    try:
        (tmp_path / "server").mkdir()  # made first, as `mkdir ~/keys; teleop keys init ~/keys`: mode 0775
        init_keys(tmp_path / "server")
        init_keys(tmp_path / "laptop", server_cert=tmp_path / "server" / "server.key")
        incoming = tmp_path / "incoming.key"  # as received: its mode is not ours to judge, the copy's is
        incoming.write_bytes((tmp_path / "laptop" / "client.key").read_bytes())
        incoming.chmod(0o666)
        authorize_key(tmp_path / "server", incoming, name="laptop")
    finally:
        os.umask(previous)
    BusSecurity.load(tmp_path / "laptop")
    assert [k.name for k in read_authorized(tmp_path / "server" / "authorized")] == ["client", "laptop"]
    assert _mode(tmp_path / "server" / "authorized" / "laptop.key") == 0o644
    assert _mode(tmp_path / "laptop" / "server.key") == 0o644


# --------------------------------------------------------------------------- owners

needs_owners = pytest.mark.skipif(not hasattr(os, "geteuid"), reason="POSIX file owners")


def _owned_by(monkeypatch, uid: int, *paths) -> None:
    """Make ``paths`` report ``uid`` as their owner: simulated, as chown needs root."""
    chosen = {os.path.abspath(p) for p in paths}
    real_stat = os.stat

    def stat_(path, *args, **kwargs):
        info = real_stat(path, *args, **kwargs)
        if isinstance(path, (str, os.PathLike)) and os.path.abspath(os.fspath(path)) in chosen:
            return os.stat_result((*info[:4], uid, *info[5:10]))
        return info

    monkeypatch.setattr(os, "stat", stat_)


def _another_user() -> int:
    """A uid that is neither this process's nor root's."""
    return next(uid for uid in (65534, 65533) if uid != os.geteuid())


@needs_owners
@pytest.mark.parametrize("relative", ["", "server.key", "client.key", "client.key_secret"])
def test_a_keys_folder_or_certificate_another_user_owns_is_refused(tmp_path, monkeypatch, relative):
    # its owner may write it whatever its mode: authorise their own key, swap the server's, read a secret
    init_keys(tmp_path / "keys")
    target, owner = tmp_path / "keys" / relative, _another_user()
    _owned_by(monkeypatch, owner, target)
    with pytest.raises(BusSecurityError, match="is owned by") as refused:
        BusSecurity.load(tmp_path / "keys")
    said = str(refused.value).replace(f"{target}/ ", f"{target} ")
    assert f"{target} is owned by uid {owner}" in said
    assert f"expected uid {os.geteuid()}" in said and "or root" in said


@needs_owners
@pytest.mark.parametrize("relative", ["authorized", "authorized/client.key"])
def test_an_authorized_folder_or_key_another_user_owns_is_refused(tmp_path, monkeypatch, relative):
    init_keys(tmp_path / "keys")
    target, owner = tmp_path / "keys" / relative, _another_user()
    _owned_by(monkeypatch, owner, target)
    with pytest.raises(BusSecurityError, match=f"{target} is owned by uid {owner}") as refused:
        read_authorized(tmp_path / "keys" / "authorized")
    assert f"chown {os.geteuid()} {target}" in str(refused.value)


@needs_owners
def test_keys_root_owns_are_accepted(tmp_path, monkeypatch):
    # as ssh accepts a root-owned authorized_keys: root may write anything anyway
    init_keys(tmp_path / "keys")
    keys = tmp_path / "keys"
    user = _another_user()  # not root, whoever runs the tests
    monkeypatch.setattr(os, "geteuid", lambda: user)
    _owned_by(monkeypatch, 0, keys, *keys.iterdir(), *(keys / "authorized").iterdir())
    BusSecurity.load(keys)
    assert [k.name for k in read_authorized(keys / "authorized")] == ["client"]


@needs_owners
def test_keys_are_not_made_in_a_folder_another_user_owns(tmp_path, monkeypatch):
    # they would be refused when loaded: refused before any is written
    (tmp_path / "keys").mkdir(mode=0o755)
    _owned_by(monkeypatch, _another_user(), tmp_path / "keys")
    with pytest.raises(BusSecurityError, match=f"{tmp_path / 'keys'} is owned by uid"):
        init_keys(tmp_path / "keys")
    assert list((tmp_path / "keys").iterdir()) == [] and _mode(tmp_path / "keys") == 0o755
