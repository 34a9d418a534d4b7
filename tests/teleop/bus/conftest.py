"""Keys for the bus's CURVE tests."""

from __future__ import annotations

import dataclasses

import pytest

from teleop.bus.security import BusSecurity, init_keys


@pytest.fixture
def keys(tmp_path) -> BusSecurity:
    init_keys(tmp_path / "keys")
    return BusSecurity.load(tmp_path / "keys")


@pytest.fixture
def stranger(tmp_path, keys) -> BusSecurity:
    """A node with its own valid keys that knows the bus's server public key (it is public)
    but whose client key the bus never authorised."""
    init_keys(tmp_path / "stranger")
    own = BusSecurity.load(tmp_path / "stranger")
    return dataclasses.replace(own, server_public_key=keys.server_public_key)
