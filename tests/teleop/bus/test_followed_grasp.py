"""RobotStateBody.followed_grasp: the one rule for an operator-driven (leader-follower) grasp."""

from __future__ import annotations

import pytest

from teleop.bus.messages import ROBOT_MODES, RobotStateBody


def _state(mode: str, grasp_id: str | None) -> RobotStateBody:
    return RobotStateBody(mode=mode, grasp_id=grasp_id, target_width_m=None, enable=False)


def test_following_names_its_grasp():
    assert _state("following", "g1").followed_grasp() == "g1"


def test_following_without_a_grasp_names_none():
    assert _state("following", None).followed_grasp() is None


@pytest.mark.parametrize("mode", [m for m in ROBOT_MODES if m != "following"])
@pytest.mark.parametrize("grasp_id", ["g1", None])
def test_other_modes_name_no_grasp(mode, grasp_id):
    assert _state(mode, grasp_id).followed_grasp() is None
