"""Export writes the gripper the session ran with into every record (for the estimator's finger stiffness)."""

from __future__ import annotations

import dataclasses

from teleop.record import read_record
from teleop.session import export_session, session_grasps


def test_exported_records_carry_the_sessions_gripper(recorded, tmp_path):
    results = [r for r in export_session(recorded.path, tmp_path / "out") if r]
    assert results
    for result in results:
        assert read_record(result.path).gripper == recorded.settings.gripper


def test_settings_given_to_the_export_give_their_gripper(recorded):
    gripper = dataclasses.replace(recorded.settings.gripper, finger_stiffness_n_per_m=4.2e4)
    settings = dataclasses.replace(recorded.settings, gripper=gripper)
    grasps = [g for g in session_grasps(recorded.path, settings=settings) if g.record is not None]
    assert grasps and all(g.record.gripper == gripper for g in grasps)
