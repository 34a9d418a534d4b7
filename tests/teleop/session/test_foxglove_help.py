"""The ``--foxglove`` help names the layout file where this installation has it."""

from __future__ import annotations

import argparse

from teleop.session import foxglove_live


def test_the_foxglove_help_names_the_installed_layout_file(tmp_path, monkeypatch):
    # It said configs/foxglove/layout.json, a path an installed wheel's user does not have.
    installed = tmp_path / "site-packages" / "teleop" / "_configs"
    monkeypatch.setattr(foxglove_live, "config_dir", lambda: installed)
    monkeypatch.setenv("COLUMNS", "1000")  # argparse wraps lines at the hyphens of a path
    parser = argparse.ArgumentParser(prog="teleop demo")
    foxglove_live.add_foxglove_argument(parser, what="the session")
    help_text = " ".join(parser.format_help().split())
    assert f"import {installed / 'foxglove' / 'layout.json'}" in help_text, help_text
