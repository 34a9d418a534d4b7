"""``--help`` of every command where the install folder has a ``%`` in it: argparse %-formats help
strings, so a help string that shows a shipped path must show it verbatim, not fail or garble."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

from teleop.clikit import help_literal

#: Every command line, with its table of subcommands.
PROGS = ("teleop", "estimator", "haptics")

#: Where the shipped configs would lie in an install folder with a ``%`` (a format directive, too).
ODD_CONFIGS = Path("/opt/100%done/configs")

#: The names through which command modules learn a shipped path (imported from teleop.settings).
PATH_SOURCES = {
    "config_dir": lambda: ODD_CONFIGS,
    "default_settings_path": lambda: ODD_CONFIGS / "settings.toml",
    "CONFIG_DIR": ODD_CONFIGS,
    "SCENE_DIR": ODD_CONFIGS / "scenes",
}

#: The commands whose help shows a shipped path in its own words (not as a ``%(default)s``).
SHOWS_PATH = {
    ("teleop", "settings"), ("teleop", "node"), ("teleop", "demo"), ("teleop", "bench-latency"),
    ("teleop", "record"), ("estimator", "build-dataset"), ("estimator", "train"), ("estimator", "fine-tune"),
    ("estimator", "pool"), ("estimator", "recalibrate"), ("estimator", "serve"), ("haptics", "serve"),
}


def _commands() -> list[tuple[str, str]]:
    return [(prog, name) for prog in PROGS for name in importlib.import_module(f"{prog}.cli").commands()]


def test_help_literal_is_shown_verbatim() -> None:
    assert help_literal(Path("/a%d/b%%c")) % {} == "/a%d/b%%c"


@pytest.mark.parametrize(("prog", "name"), _commands())
def test_help_shows_a_percent_install_path(prog: str, name: str, monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    cli = importlib.import_module(f"{prog}.cli")
    importlib.import_module(cli.commands()[name].module)
    for module in list(sys.modules.values()):
        if (getattr(module, "__name__", "") or "").partition(".")[0] not in PROGS:
            continue
        for attr, value in PATH_SOURCES.items():
            if attr in vars(module):
                monkeypatch.setattr(module, attr, value)
    with pytest.raises(SystemExit) as exit_:
        cli.main([name, "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "100%%" not in out
    if (prog, name) in SHOWS_PATH:
        assert "/opt/100%done/configs" in out
