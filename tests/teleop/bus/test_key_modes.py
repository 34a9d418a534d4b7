"""A keys folder, its authorized/ folder or a public certificate that other users may write is refused,
naming the path and the chmod (teleop.bus.cert_access.check_owner_writes)."""

from __future__ import annotations

import os
import stat

import pytest

from teleop.bus.security import BusSecurity, authorize_key, init_keys, read_authorized
from teleop.errors import BusSecurityError


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
