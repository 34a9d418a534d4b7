"""A demo grasp the robot node cut short (its watchdog, a failed gripper command): the closing table,
the live line and ``--json`` say so, with the notice's reason, instead of showing a bare refusal."""

from __future__ import annotations

import io
import json
from pathlib import Path

from support.bus import ReplayedEvents, message_from
from support.outcomes import outcome

from teleop.bus.messages import RobotNoticeBody
from teleop.catalogue import ObjectSpec
from teleop.settings import default_settings_path, load_settings
from teleop.system.demo_table import LiveView, closing_table, felt_summary
from teleop.system.live_system import LiveSystem

STALLED = ("the robot node itself stalled for 0.357 s (watchdog 0.2 s): the fingers stopped")
SPONGE = ObjectSpec(name="sponge", shape="box", material="foam", modulus_pa=3e4)


def _watchdog(grasp_id: str | None = "g") -> RobotNoticeBody:
    return RobotNoticeBody(event="watchdog", action="follow", grasp_id=grasp_id, reason=STALLED)


def test_a_grasp_the_watchdog_cut_shows_the_cause_in_the_table_line_and_json():
    range_pa = (5e3, 6.75e6)
    ran = outcome("duck", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 150.0, display_range=range_pa)
    ran.renderer_report = {"latency_ms": 150.0, "display_fraction": 0.5, "rigid": False, "unknown": False}
    cut = outcome("sponge", 3e4, {"E_pa": None, "interval_pa": [None, None], "state": "insufficient_data"},
                  None, None, display_range=range_pa)
    cut.ended_by = _watchdog()
    table = closing_table([ran, cut]).splitlines()
    assert table[0].split()[-1] == "note"
    assert table[2].split()[-1] == "-" and table[3].endswith("cut: watchdog")
    assert table[4] == f"sponge (g) cut by the robot node (watchdog): {STALLED}"
    # The summary's figures stay as they were: the cut grasp was not rendered.
    assert felt_summary([ran, cut])["not_rendered"] == 1 and table[-2].endswith("1 not rendered")
    assert json.loads(json.dumps(cut.to_json()))["ended_by"] == {"event": "watchdog", "action": "follow",
                                                                  "reason": STALLED}
    assert ran.to_json()["ended_by"] is None
    # Without a cut grasp the table has no note column and no cut line.
    alone = closing_table([ran]).splitlines()
    assert "note" not in alone[0] and not any("cut" in line for line in alone)
    cut.robot_ended = cut.estimator_ended = True
    assert LiveView(io.StringIO(), 2).line(2, cut).endswith(", cut: watchdog")


def _replaying(tmp_path: Path, grasp_id: str, messages: list) -> LiveSystem:
    """A demo's live system whose bus replays ``messages``; the estimator's log names ``grasp_id``."""
    system = LiveSystem(Path("settings.toml"), "quick", tmp_path, Path("calibration.npz"))
    (tmp_path / "estimator.jsonl").write_text(f'{{"grasp_id": "{grasp_id}"}}\n')
    system.events = ReplayedEvents(messages)
    return system


def test_following_a_grasp_keeps_the_notice_that_ended_it_and_no_other(tmp_path: Path):
    system = _replaying(tmp_path, "grasp-1", [
        # Before the operator's grasp starts: a load cell's notice names no grasp.
        message_from("robot", "robot_notice", event="device", action="load_cell", grasp_id=None, reason="reads failed"),
        message_from("robot", "grasp_event", event="start", grasp_id="grasp-1", object_name="sponge"),
        message_from("robot", "robot_notice", event="force_limit", action="follow", grasp_id="grasp-1", reason="max force"),
        message_from("robot", "robot_notice", event="watchdog", action="follow", grasp_id="grasp-1", reason=STALLED),
        # The follows queued while the node stalled, refused: they do not replace what ended it.
        message_from("robot", "robot_notice", event="refused", action="follow", grasp_id="grasp-1", reason="ended"),
        message_from("robot", "grasp_event", event="end", grasp_id="grasp-1"),
        message_from("estimator", "grasp_event", event="end", grasp_id="grasp-1"),
    ])
    followed = system.operated_grasp(SPONGE, timeout_s=30.0)
    assert followed.grasp_id == "grasp-1" and followed.ended_by is not None
    assert (followed.ended_by.event, followed.ended_by.reason) == ("watchdog", STALLED)


def test_a_grasp_that_ran_its_course_has_no_ended_by(tmp_path: Path):
    system = _replaying(tmp_path, "grasp-2", [
        message_from("robot", "grasp_event", event="start", grasp_id="grasp-2", object_name="sponge"),
        message_from("robot", "robot_notice", event="force_limit", action="follow", grasp_id="grasp-2", reason="max force"),
        message_from("robot", "grasp_event", event="end", grasp_id="grasp-2"),
        message_from("estimator", "grasp_event", event="end", grasp_id="grasp-2"),
    ])
    assert system.operated_grasp(SPONGE, timeout_s=30.0).ended_by is None


def test_a_message_of_another_grasp_mid_grasp_does_not_stop_the_bus_being_read(tmp_path: Path):
    # Set aside for a later grasp, a message came straight back before anything on the bus: the
    # grasp's own end was never read, and the demo waited out its timeout.
    system = _replaying(tmp_path, "grasp-1", [
        message_from("robot", "grasp_event", event="start", grasp_id="grasp-1", object_name="sponge"),
        # a stale follow of a grasp that never went live, refused; then the next grasp starts early
        message_from("robot", "robot_notice", event="refused", action="follow", grasp_id="grasp-0", reason="ended"),
        message_from("robot", "grasp_event", event="end", grasp_id="grasp-1"),
        message_from("robot", "grasp_event", event="start", grasp_id="grasp-2", object_name="sponge"),
        message_from("estimator", "grasp_event", event="end", grasp_id="grasp-1"),
        message_from("robot", "grasp_event", event="end", grasp_id="grasp-2"),
        message_from("estimator", "grasp_event", event="end", grasp_id="grasp-2"),
    ])
    (tmp_path / "estimator.jsonl").write_text("".join(f'{{"grasp_id": "grasp-{n}"}}\n' for n in (1, 2)))
    assert system.operated_grasp(SPONGE, timeout_s=2.0).grasp_id == "grasp-1"
    assert system.operated_grasp(SPONGE, timeout_s=2.0).grasp_id == "grasp-2"  # its start, set aside, counts


def test_what_the_operator_did_ahead_waits_for_its_grasps_and_keeps_what_cut_them(tmp_path: Path):
    # The estimator's end of grasp-1 comes last: grasp-2 and grasp-3 ran meanwhile, grasp-2 cut short.
    system = _replaying(tmp_path, "grasp-1", [
        message_from("robot", "grasp_event", event="start", grasp_id="grasp-1", object_name="sponge"),
        message_from("robot", "grasp_event", event="end", grasp_id="grasp-1"),
        message_from("robot", "grasp_event", event="start", grasp_id="grasp-2", object_name="sponge"),
        message_from("robot", "robot_notice", event="watchdog", action="follow", grasp_id="grasp-2", reason=STALLED),
        message_from("robot", "grasp_event", event="end", grasp_id="grasp-2"),
        message_from("estimator", "grasp_event", event="end", grasp_id="grasp-2"),
        message_from("robot", "grasp_event", event="start", grasp_id="grasp-3", object_name="sponge"),
        message_from("robot", "grasp_event", event="end", grasp_id="grasp-3"),
        message_from("estimator", "grasp_event", event="end", grasp_id="grasp-3"),
        message_from("estimator", "grasp_event", event="end", grasp_id="grasp-1"),
    ])
    (tmp_path / "estimator.jsonl").write_text("".join(f'{{"grasp_id": "grasp-{n}"}}\n' for n in (1, 2, 3)))
    followed = [system.operated_grasp(SPONGE, timeout_s=2.0) for _ in range(3)]
    assert [o.grasp_id for o in followed] == ["grasp-1", "grasp-2", "grasp-3"]
    assert [o.ended_by and o.ended_by.event for o in followed] == [None, "watchdog", None]


def test_the_demo_subscribes_to_the_robot_nodes_notices(tmp_path: Path):
    system = LiveSystem(default_settings_path(), "quick", tmp_path, tmp_path / "calibration.npz")
    try:
        system.open_bus(load_settings(default_settings_path()))
        assert "robot_notice" in system.events.topics
    finally:
        system.stop()
