"""``haptics try``, ``encode``, ``devices`` and ``protocol`` with ``--json``: stdout is the JSON object
alone (the text goes to stderr), and ``try`` names its fields as ``estimator estimate`` and the
renderer do."""

from __future__ import annotations

import json

import pytest

from haptics.cli import main
from teleop.units import format_pa


@pytest.mark.parametrize("options", [
    ["protocol"],
    ["encode", "--level", "100"],
    ["devices"],
    ["try", "--backend", "sim", "--e-pa", "2e5"],
    ["try", "--backend", "sim", "--state", "insufficient_data"],
])
def test_json_is_all_of_stdout_and_the_text_goes_to_stderr(fake_hid, options, capsys):
    assert main([*options, "--json"]) == 0
    captured = capsys.readouterr()
    assert isinstance(json.loads(captured.out), dict)  # one object, nothing before it
    assert captured.err.strip()  # the human text, still shown
    assert main(options) == 0
    assert capsys.readouterr().out.strip() == captured.err.strip()  # the same text, without --json


def test_try_names_the_modulus_and_fraction_as_estimate_and_the_renderer_do(capsys):
    assert main(["try", "--backend", "sim", "--e-pa", "2e5", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["E_pa"] == 2e5 and 0.0 < data["display_fraction"] < 1.0
    assert "e_pa" not in data and "stiffness" not in data
    # A refusal carries no modulus, even when one was given (estimator estimate gives E_pa null).
    assert main(["try", "--backend", "sim", "--state", "insufficient_data", "--e-pa", "2e5", "--json"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data["E_pa"] is None and data["display_fraction"] == 0.0 and data["command"]["unknown"] is True
    assert captured.err.startswith("no modulus (insufficient_data) -> ")  # not "E None Pa"


@pytest.mark.parametrize(("options", "e_pa"), [
    (["--state", "lower_bound", "--low-pa", "1e5"], 1e5),
    (["--state", "upper_bound", "--high-pa", "3e4"], 3e4),
    (["--state", "lower_bound", "--e-pa", "2e5", "--low-pa", "1e5"], 2e5),
])
def test_try_gives_the_modulus_rendered_for_a_bound_from_the_interval(options, e_pa, capsys):
    assert main(["try", "--backend", "sim", *options, "--json"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert data["E_pa"] == e_pa and 0.0 < data["display_fraction"] < 1.0
    assert f"E {format_pa(e_pa)} ({data['state']})" in captured.err  # the text line says it too, not "E None"
