"""A secret certificate whose secret key does not give its public key is refused when the keys load,
naming the file, and `teleop doctor` says so (teleop.bus.cert_keys)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from teleop.bus.security import BusSecurity, init_keys, list_keys
from teleop.errors import BusSecurityError
from teleop.settings import BusSettings, Settings
from teleop.system.doctor import check_endpoints

_SECRET_LINE = re.compile(r'(secret-key = ")([^"]{40})(")')


def _damage_secret(path: Path) -> None:
    """Change one character of the secret key: still 40 valid Z85 characters, mode kept."""
    text = path.read_text()
    key = _SECRET_LINE.search(text).group(2)
    changed = key[:7] + ("a" if key[7] != "a" else "b") + key[8:]
    path.write_text(_SECRET_LINE.sub(lambda m: m.group(1) + changed + m.group(3), text))


def _swap_secret(path: Path, other: Path) -> None:
    """Keep ``path``'s public-key line, take ``other``'s secret key (another pair's)."""
    secret = _SECRET_LINE.search(other.read_text()).group(2)
    path.write_text(_SECRET_LINE.sub(lambda m: m.group(1) + secret + m.group(3), path.read_text()))


@pytest.mark.parametrize("name", ["server", "client"])
@pytest.mark.parametrize("spoil", ["damaged", "another pair"])
def test_a_secret_key_that_does_not_give_its_public_key_is_refused_naming_the_file(tmp_path, name, spoil):
    init_keys(tmp_path / "keys")
    init_keys(tmp_path / "other")
    secret = tmp_path / "keys" / f"{name}.key_secret"
    if spoil == "damaged":
        _damage_secret(secret)
    else:
        _swap_secret(secret, tmp_path / "other" / f"{name}.key_secret")
    assert secret.stat().st_mode & 0o777 == 0o600
    expected = (f"{secret}: its secret key does not match its public key (damaged, or from another pair): "
                "copy the pair")
    for load in (BusSecurity.load, list_keys):  # the keys of every command, `teleop keys list` among them
        with pytest.raises(BusSecurityError) as refused:
            load(tmp_path / "keys")
        assert str(refused.value).startswith(expected), refused.value
        assert "`teleop keys init NEWDIR`" in str(refused.value)


def test_doctor_reports_a_damaged_server_secret_key(tmp_path):
    init_keys(tmp_path / "keys")
    secret = tmp_path / "keys" / "server.key_secret"
    _damage_secret(secret)
    checks = {c.name: c for c in check_endpoints(Settings(bus=BusSettings(keys_dir=str(tmp_path / "keys"))))}
    keys = checks["bus keys"]
    assert not keys.ok
    assert f"{secret}: its secret key does not match its public key" in keys.problem
