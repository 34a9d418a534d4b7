"""The estimator's help texts state the intervals the model card states (every command's help is
checked for Python values in tests/teleop/test_cli.py)."""

from __future__ import annotations

import argparse
import importlib

from teleop.clikit import _DefaultsHelpFormatter


def help_text(module: str) -> str:
    parser = argparse.ArgumentParser(prog="estimator x", formatter_class=_DefaultsHelpFormatter)
    importlib.import_module(module).add_arguments(parser)
    return parser.format_help()


def test_estimate_states_the_model_cards_interval():
    text = " ".join(help_text("estimator.estimate_cli").split())
    assert "90 % for a learned model" in text and "95 %" in text
