"""The check that a contract suite runs every backend of its family's table fails naming what to add."""

from __future__ import annotations

import pytest
from support.contract import assert_every_backend_covered, param_names


def test_params_are_named_plain_or_marked():
    assert param_names(["sim", pytest.param("franky", marks=pytest.mark.robot_sim)]) == {"sim", "franky"}


def test_a_backend_without_a_parameter_is_named_with_the_fixture_to_add_it_to():
    assert_every_backend_covered("gripper", ["sim", "franky"], {"sim", "franky", "hardware"},
                                 fixture="gripper", where="x.py")
    with pytest.raises(AssertionError, match=r"gripper backend\(s\) 'sim_slow' in BACKENDS never run the "
                                             r"contract suite: add a parameter for each to the `gripper` fixture in x.py"):
        assert_every_backend_covered("gripper", ["sim", "franky", "sim_slow"], {"sim", "franky"},
                                     fixture="gripper", where="x.py")
