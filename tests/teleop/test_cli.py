"""The console scripts: help lists every subcommand, errors are one line, options are explained."""

from __future__ import annotations

import argparse
import importlib
import json
import re
import shlex
import subprocess
import sys
import types
from importlib import metadata
from pathlib import Path

import pytest

import estimator.cli
import haptics.cli
import teleop.cli
from teleop.clikit import EXTRA_MODULES, Command, _DefaultsHelpFormatter, run_cli
from teleop.scene import SCENE_DIR
from teleop.settings import CONFIG_DIR

BIN = Path(sys.executable).parent
PACKAGES = {"teleop": teleop.cli.commands(), "estimator": estimator.cli.commands(), "haptics": haptics.cli.commands()}


def run_script(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / argv[0]), *argv[1:]], capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize("prog", sorted(PACKAGES))
def test_help_lists_every_subcommand(prog):
    result = run_script(prog, "--help")
    assert result.returncode == 0, result.stderr
    assert f"usage: {prog}" in result.stdout and "``" not in result.stdout  # the docstring's markup stripped
    for name in PACKAGES[prog]:
        assert name in result.stdout, f"{prog} --help does not list {name}"


@pytest.mark.parametrize("prog", sorted(PACKAGES))
def test_the_readme_names_every_command(prog):
    commands = (ROOT / "README.md").read_text().split("## Commands", 1)[1].split("\n## ", 1)[0]
    listed = next(item for item in commands.split("\n- ") if item.startswith(f"`{prog}`"))
    assert [name for name in PACKAGES[prog] if f"`{name}`" not in listed] == []


@pytest.mark.parametrize("prog", sorted(PACKAGES))
def test_version_prints_the_installed_version(prog):
    result = run_script(prog, "--version")
    assert result.returncode == 0, result.stderr
    assert result.stdout == f"{prog} {metadata.version('compliance-teleop')}\n"


def test_version_without_the_distribution_installed_is_no_crash(monkeypatch, capsys):
    def not_installed(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", not_installed)
    with pytest.raises(SystemExit) as exit_:
        haptics.cli.main(["--version"])
    assert exit_.value.code == 0 and capsys.readouterr().out == (
        "haptics (version unknown: the compliance-teleop distribution is not installed)\n")


def test_teleop_has_the_foundation_commands():
    assert {"settings", "catalogue", "import-dataset"} <= set(teleop.cli.commands())


def test_settings_on_a_bad_file_is_one_line_without_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[gripper]\nmax_width_m = -1.0\n")
    result = run_script("teleop", "settings", str(bad))
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("teleop settings: error: ") and str(bad) in lines[0] and "max_width_m" in lines[0]
    assert "Traceback" not in result.stderr


def test_settings_on_a_missing_file_exits_2(tmp_path):
    result = run_script("teleop", "settings", str(tmp_path / "absent.toml"))
    assert result.returncode == 2 and "cannot read settings file" in result.stderr
    assert "Traceback" not in result.stderr


def test_settings_prints_the_resolved_settings():
    result = run_script("teleop", "settings")
    assert result.returncode == 0, result.stderr
    resolved = json.loads(result.stdout)
    assert resolved["sensors"]["left"]["gel_modulus_pa"] == 275000.0


def test_settings_warns_of_a_calibration_file_that_does_not_exist(tmp_path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text((CONFIG_DIR / "settings.toml").read_text())  # outside configs/: its relative paths miss
    assert teleop.cli.main(["settings", str(rig)]) == 0
    err = capsys.readouterr().err
    assert f"[sensors.left] calibration {tmp_path / 'calibration'}" in err and "no such file" in err
    assert f"resolves against {tmp_path}" in err
    assert teleop.cli.main(["settings"]) == 0 and "warning" not in capsys.readouterr().err  # the shipped ones exist


def test_settings_takes_its_file_as_settings_too_as_every_command_does(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[gripper]\nmax_width_m = -1.0\n")
    assert teleop.cli.main(["settings", "--settings", str(bad)]) == 2
    assert f"{bad}: " in capsys.readouterr().err
    assert teleop.cli.main(["settings", str(bad), "--settings", str(bad)]) == 2
    assert "name the settings file once" in capsys.readouterr().err


def test_a_reader_that_leaves_early_is_no_error_of_the_command():
    # stdout's reader is gone before the command prints (as `haptics protocol | head -1` can be)
    proc = subprocess.Popen([str(BIN / "haptics"), "protocol"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1 and err == b""


def test_unknown_subcommand_is_a_usage_error():
    result = run_script("teleop", "no-such-command")
    assert result.returncode == 2 and "invalid choice" in result.stderr


def test_import_dataset_help_explains_every_option():
    result = run_script("teleop", "import-dataset", "--help")
    assert result.returncode == 0, result.stderr
    for option in ("--layout", "--out", "--objects", "--settings", "--fps", "--overwrite", "--json", "{raw,preprocessed}"):
        assert option in result.stdout


def _command_module(monkeypatch, name: str, imports: str) -> None:
    """A command module ``name`` whose run imports ``imports``."""
    module = types.ModuleType(name)
    module.add_arguments = lambda parser: None
    module.run = lambda args: importlib.import_module(imports)
    monkeypatch.setitem(sys.modules, name, module)


def test_a_command_whose_extra_is_missing_says_what_to_install_in_one_line(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "torch", None)  # `import torch` raises ImportError, as when not installed
    _command_module(monkeypatch, "fit_cli", "torch")
    assert run_cli("prog", "doc", {"fit": Command("fit_cli", "fit a model", extra="train")}, ["fit"]) == 2
    assert capsys.readouterr().err == ("prog fit: error: needs the 'train' extra (import of torch halted; None in "
                                       "sys.modules): pip install 'compliance-teleop[train]' (in a checkout: "
                                       "pip install -c constraints.txt -e '.[train]')\n")


def test_a_missing_module_that_is_not_the_commands_extra_stays_a_traceback(monkeypatch):
    # Not an install the user can fix by the extra: a bug to see in full.
    monkeypatch.setitem(sys.modules, "torch", None)
    monkeypatch.setitem(sys.modules, "not_installed_here", None)
    _command_module(monkeypatch, "fit_cli", "not_installed_here")
    with pytest.raises(ImportError):
        run_cli("prog", "doc", {"fit": Command("fit_cli", "fit a model", extra="train")}, ["fit"])
    _command_module(monkeypatch, "plain_cli", "torch")
    with pytest.raises(ImportError):
        run_cli("prog", "doc", {"plain": Command("plain_cli", "no extra named")}, ["plain"])


def test_every_extra_a_command_names_is_known():
    named = {c.extra for commands in PACKAGES.values() for c in commands.values()} - {None}
    assert named and named <= set(EXTRA_MODULES)


@pytest.mark.parametrize("module", ["teleop.node_cli", "teleop.system.demo"])
def test_scene_help_names_the_installed_scenes_folder_not_the_source_trees(module):
    parser = argparse.ArgumentParser(formatter_class=_DefaultsHelpFormatter)
    importlib.import_module(module).add_arguments(parser)
    scene = next(a for a in parser._actions if "--scene" in a.option_strings)
    assert str(SCENE_DIR) in scene.help and "configs/scenes/" not in scene.help


def _commands():
    for prog, commands in sorted(PACKAGES.items()):
        for name, command in commands.items():
            yield pytest.param(prog, name, command.module, id=f"{prog}-{name}")


@pytest.mark.parametrize(("prog", "name", "module"), list(_commands()))
def test_every_option_of_every_command_is_explained_as_a_person_would(prog, name, module):
    mod = importlib.import_module(module)
    assert callable(mod.run), f"{module} has no run(args)"
    parser = argparse.ArgumentParser(prog=f"{prog} {name}", formatter_class=_DefaultsHelpFormatter)
    mod.add_arguments(parser)
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help and len(action.help.strip()) > 10, \
            f"{prog} {name}: {action.option_strings or action.dest} has no help"
    # As printed: no Python values ("None: ...", "(default: (64, 88))"), no unexpanded format codes.
    text = " ".join(parser.format_help().split())
    assert not re.search(r"\bNone\b", text), f"{prog} {name}"
    assert not re.search(r"\(default: [(\[][-\d'\"\])]", text), f"{prog} {name}"
    assert "(default: )" not in text and "``" not in text, f"{prog} {name}"
    assert "%(" not in text and "%%" not in text


# --------------------------------------------------------------------------- commands the docs give

ROOT = Path(__file__).resolve().parents[2]
DOCS = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "estimator/models/default/MODEL_CARD.md")


def _documented_commands():
    """(page, line, prog, argv) of every console-script call in the docs' ``sh`` blocks."""
    for page in DOCS:
        text = page.read_text()
        for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
            for line in block.replace("\\\n", " ").splitlines():
                for part in re.split(r"&&|[&;|]", line.split("#")[0]):
                    words = [w for w in shlex.split(part) if not re.fullmatch(r"[A-Z_]+=\S*", w)]
                    if words and Path(words[0]).name in PACKAGES and len(words) > 1:
                        yield pytest.param(page.name, part.strip(), Path(words[0]).name, words[1:],
                                           id=f"{page.name}:{' '.join(words[:2])}")


@pytest.mark.parametrize(("page", "line", "prog", "argv"), list(_documented_commands()))
def test_every_command_the_docs_give_parses(page, line, prog, argv):
    command = PACKAGES[prog].get(argv[0])
    assert command is not None, f"{page}: {line!r}: {prog} has no command {argv[0]!r}"
    parser = argparse.ArgumentParser(prog=f"{prog} {argv[0]}", formatter_class=_DefaultsHelpFormatter)
    importlib.import_module(command.module).add_arguments(parser)
    try:
        parser.parse_args(argv[1:])
    except SystemExit:
        pytest.fail(f"{page}: {line!r} does not parse")
