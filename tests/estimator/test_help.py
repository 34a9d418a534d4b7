"""The estimator's help texts state the intervals the model card states, and its dataset, training
and evaluation commands describe themselves (every option's help of every command is checked in
tests/teleop/test_cli.py)."""

from __future__ import annotations

import argparse
import importlib

import pytest
from support.extras import estimator_without_torch

from teleop.clikit import _DefaultsHelpFormatter


def help_text(module: str) -> str:
    parser = argparse.ArgumentParser(prog="estimator x", formatter_class=_DefaultsHelpFormatter)
    importlib.import_module(module).add_arguments(parser)
    return parser.format_help()


def test_estimate_states_the_model_cards_interval():
    text = " ".join(help_text("estimator.estimate_cli").split())
    # ... and that the analytical fits' intervals are not calibrated to a level (they leave out the
    # contact model's error)
    assert "90 % for a learned model" in text and "without the error of the contact mechanics" in text


@pytest.mark.parametrize("module", ["estimator.training.dataset_cli", "estimator.training.train_cli",
                                    "estimator.training.finetune_cli", "estimator.evaluation.bench_cli",
                                    "estimator.evaluation.evaluate_cli", "estimator.estimate_cli"])
def test_the_command_has_a_description(module):
    parser = argparse.ArgumentParser()
    importlib.import_module(module).add_arguments(parser)
    assert parser.description


def test_serve_says_reload_sends_on_the_control_endpoint_and_it_listens_on_both():
    # estimator reload binds bus.control (estimator/reload_cli.py); serve subscribes to command and control.
    text = " ".join(help_text("estimator.service_cli").split())
    assert "(a load_model message on --control)" in text and "on --command and --control alike" in text
    assert "load_model message on --command" not in text


@pytest.mark.slow
@pytest.mark.parametrize("command", ["train", "fine-tune", "pool", "recalibrate"])
def test_the_model_commands_help_needs_no_torch(command):
    result = estimator_without_torch(command, "--help")
    assert result.returncode == 0, result.stderr
    assert f"usage: estimator {command}" in result.stdout


@pytest.mark.slow
@pytest.mark.parametrize("argv", [["train", "--data", "d", "--out", "m"],
                                  ["fine-tune", "--model", "m", "--data", "d", "--out", "o"],
                                  ["pool", "--model", "a", "--model", "b", "--data", "d", "--out", "o"]])
def test_a_model_command_without_torch_says_to_install_the_train_extra_in_one_line(argv):
    result = estimator_without_torch(*argv)
    assert result.returncode == 2
    assert result.stderr == (f"estimator {argv[0]}: error: needs the 'train' extra (No module named 'torch'): "
                             "pip install 'compliance-teleop[train]' (in a checkout: "
                             "pip install -c constraints.txt -e '.[train]')\n")
