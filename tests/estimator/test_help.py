"""The estimator's help texts say what a person would: no Python values, the intervals the model card states."""

from __future__ import annotations

import argparse
import importlib
import re

import pytest

from estimator.cli import COMMANDS
from teleop.clikit import _DefaultsHelpFormatter


def help_text(module: str) -> str:
    parser = argparse.ArgumentParser(prog="estimator x", formatter_class=_DefaultsHelpFormatter)
    importlib.import_module(module).add_arguments(parser)
    return parser.format_help()


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_shows_no_python_values(name):
    text = " ".join(help_text(COMMANDS[name].module).split())
    assert not re.search(r"\bNone\b", text), name
    assert not re.search(r"\(default: [(\[][-\d'\"\])]", text), name  # tuples and lists as Python prints them
    assert "%(" not in text and "%%" not in text


def test_estimate_states_the_model_cards_interval():
    text = " ".join(help_text("estimator.estimate_cli").split())
    assert "90 % for a learned model" in text and "95 %" in text


def test_compare_explains_every_option():
    parser = argparse.ArgumentParser()
    importlib.import_module("estimator.compare_cli").add_arguments(parser)
    assert parser.description
    assert all(action.help for action in parser._actions)
