"""Export writes the rig the session ran with into every record (the gripper for the estimator's finger
stiffness), and warns when given settings name other sensors."""

from __future__ import annotations

import dataclasses
import logging

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


def test_settings_naming_other_sensors_are_warned_of(recorded, caplog):
    sensors = tuple(dataclasses.replace(s, model="mini", optics="gelsight_mini") if s.finger == "left" else s
                    for s in recorded.settings.sensors)
    with caplog.at_level(logging.WARNING, logger="teleop.session.export"):
        grasps = [g for g in session_grasps(recorded.path, settings=dataclasses.replace(recorded.settings,
                                                                                       sensors=sensors)) if g]
    assert grasps and all(g.record.sensor("left").model == "mini" for g in grasps)  # as given
    warned = [r.getMessage() for r in caplog.records if "the session ran finger 'left'" in r.getMessage()]
    assert len(warned) == 1 and "model 'wedge', optics 'wedge'" in warned[0] and "model 'mini'" in warned[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="teleop.session.export"):
        list(session_grasps(recorded.path, settings=recorded.settings))
    assert not [r for r in caplog.records if "the session ran" in r.getMessage()]
