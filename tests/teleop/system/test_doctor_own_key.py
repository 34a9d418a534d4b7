"""`teleop doctor` and this host's own client key: not authorised while every endpoint is bound here, its
processes refuse each other (not ready); with peers elsewhere it is a note (teleop.system.doctor)."""

from __future__ import annotations

import shutil

from teleop.bus.security import init_keys
from teleop.settings import BusSettings, Settings
from teleop.system.doctor import ENDPOINTS, Check, _keys_check, check_endpoints


def _keys_without_own_client(tmp_path):
    """A keys folder whose authorized/ holds another host's client key but not this host's own."""
    init_keys(tmp_path / "keys")
    init_keys(tmp_path / "laptop", server_cert=tmp_path / "keys" / "server.key")
    authorized = tmp_path / "keys" / "authorized"
    (authorized / "client.key").unlink()
    shutil.copyfile(tmp_path / "laptop" / "client.key", authorized / "laptop.key")
    return tmp_path / "keys"


def test_this_hosts_client_key_not_authorised_with_every_endpoint_here_is_not_ready(tmp_path):
    keys_dir = _keys_without_own_client(tmp_path)
    checks = {c.name: c for c in check_endpoints(Settings(bus=BusSettings(keys_dir=str(keys_dir))))}
    assert all(checks[name].detail["here"] for name in ENDPOINTS)
    keys = checks["bus keys"]
    assert not keys.ok, keys
    assert f"this host's client key {keys_dir / 'client.key'} is not authorised in {keys_dir / 'authorized'}" in keys.problem
    assert f"run `teleop keys add {keys_dir} {keys_dir / 'client.key'}`" in keys.problem


def test_this_hosts_client_key_not_authorised_with_peers_elsewhere_is_a_note(tmp_path):
    keys_dir = _keys_without_own_client(tmp_path)
    bus = BusSettings(keys_dir=str(keys_dir))
    endpoints = [Check(name, True, detail={"endpoint": getattr(bus, name), "here": name != "command"})
                 for name in ENDPOINTS]  # the console's command endpoint is bound on another host
    keys = _keys_check(Settings(bus=bus), endpoints)
    assert keys.ok and keys.problem is None
    assert keys.detail["note"].endswith(f"this host's client key {keys_dir / 'client.key'} is not authorised in "
                                        f"{keys_dir / 'authorized'}: this host's own processes cannot connect to what it binds")
