"""A path in a settings file that starts with ``~`` is in the home folder, as ``teleop keys --help`` writes
``keys_dir = "~/keys"`` (teleop.settings_paths.resolve_path)."""

from __future__ import annotations

from teleop.settings import load_settings, resolve_path


def test_a_home_relative_path_resolves_to_the_home_folder_not_beside_the_settings(tmp_path, monkeypatch):
    home = tmp_path / "home"
    monkeypatch.setenv("HOME", str(home))
    settings = tmp_path / "rig" / "settings.toml"
    settings.parent.mkdir()
    settings.write_text('[bus]\nkeys_dir = "~/keys"\n', encoding="utf-8")
    assert load_settings(settings).bus.keys_dir == str(home / "keys")
    assert resolve_path("~/keys", folder=tmp_path) == home / "keys"
    assert resolve_path("keys", folder=tmp_path) == tmp_path / "keys"  # a relative path: beside the file, as before
