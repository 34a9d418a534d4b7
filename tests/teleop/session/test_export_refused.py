"""Export of what the live path knows and the log reader refuses: a leader-follower grasp's style, the
robot notice that cut a grasp short, and stored messages the reader refuses (counted, their grasps flagged, a log of nothing else named so)."""

from __future__ import annotations

import json

import numpy as np
from mcap.reader import make_reader
from mcap.writer import Writer

from teleop.bus import Publisher
from teleop.catalogue import default_catalogue_path
from teleop.cli import main
from teleop.record import read_record
from teleop.session import export_session
from teleop.session.logfile import BUS_ENCODINGS


def _publish_grasp(pub, gid, t, rng, helpers, *, follow):
    """One grasp as the robot node sends it; a follow grasp with the operator's ``follow`` messages and
    the node's ``robot_state`` mode ``following`` (as `teleop demo --operator sim` logs them)."""
    sent = [pub.send("grasp_event", t_capture_s=t, event="start", grasp_id=gid, object_name=helpers.object_name)]
    for k in range(3):
        t += 1 / 30
        if follow:
            sent.append(pub.send("follow", t_capture_s=t, grasp_id=gid, target_width_m=0.05, enable=True))
        sent.append(pub.send("robot_state", t_capture_s=t, mode="following" if follow else "grasping",
                             grasp_id=gid, target_width_m=0.05 if follow else None, enable=follow))
        sent.append(pub.send("frame", t_capture_s=t, finger="left", grasp_id=gid, index=k, encoding="jpeg",
                             data=helpers.jpeg(rng)))
        sent.append(pub.send("force", t_capture_s=t, grasp_id=gid, t_s=[t - 0.01, t], value_n=[1.0, 2.0 + k]))
        sent.append(pub.send("width", t_capture_s=t, grasp_id=gid, t_s=[t], value_m=[0.05 - 0.001 * k]))
    sent.append(pub.send("grasp_event", t_capture_s=t + 0.1, event="end", grasp_id=gid))
    return sent


def _exported(path, publish, session_settings, helpers) -> dict:
    """Records by grasp id of a session whose robot publisher ``publish(pub)`` sent its messages (it returns them)."""
    with (
        Publisher("tcp://127.0.0.1:*", lossless=True, source="robot") as pub,
        helpers.recording(path, [pub.endpoint], settings=session_settings,
                          catalogue=default_catalogue_path()) as recorder,
    ):
        pub.wait_for_subscriber("")
        sent = publish(pub)
        helpers.wait_for(lambda: recorder.stats.messages == len(sent), what="the session recorded")
    return {g.grasp_id: read_record(g.path) for g in export_session(path, path.parent / "records", source="hardware")}


def test_a_leader_follower_grasp_is_exported_as_operator_driven(session_settings, helpers, tmp_path):
    rng = np.random.default_rng(3)

    def publish(pub):
        return (_publish_grasp(pub, "scripted", 10.0, rng, helpers, follow=False)
                + _publish_grasp(pub, "operated", 20.0, rng, helpers, follow=True))

    records = _exported(tmp_path / "operated.mcap", publish, session_settings, helpers)
    assert {gid: record.provenance.style for gid, record in records.items()} == {
        "scripted": "script", "operated": "operator"}


def test_a_grasp_the_watchdog_cut_short_says_so_in_its_events(session_settings, helpers, tmp_path):
    rng = np.random.default_rng(4)
    stopped = "no follow command for 0.21 s: the fingers stopped"

    def publish(pub):
        sent = _publish_grasp(pub, "whole", 10.0, rng, helpers, follow=True)
        # Ended notices outside a grasp's time: the one before "cut" started names its id (a node restarted).
        sent.append(pub.send("robot_notice", t_capture_s=19.0, event="watchdog", action="follow", grasp_id="cut",
                             reason=stopped))
        sent.append(pub.send("robot_notice", t_capture_s=20.05, event="refused", action="follow", grasp_id="cut",
                             reason="a refusal ends no grasp"))
        sent.append(pub.send("robot_notice", t_capture_s=20.06, event="watchdog", action="follow", grasp_id="cut",
                             reason=stopped))
        return sent + _publish_grasp(pub, "cut", 20.0, rng, helpers, follow=True)

    events = {gid: record.events for gid, record in _exported(tmp_path / "cut.mcap", publish, session_settings,
                                                              helpers).items()}
    assert not any(key.startswith("stopped_by") for key in events["whole"])
    assert events["cut"]["stopped_by_watchdog"] == 20.06
    assert set(events["cut"]) == {"grasp_start", "grasp_end", "stopped_by_watchdog"}


def _spoiled(recorded, out, spoil):
    """A copy of the recorded log whose n-th bus message on topic ``force`` (from 1; every bus message
    when ``spoil`` is "all") lost its last 5 bytes: one the log reader refuses as corrupt."""
    forces = 0
    with recorded.path.open("rb") as f, out.open("wb") as g:
        reader, writer = make_reader(f), Writer(g)
        summary, header = reader.get_summary(), reader.get_header()
        writer.start(profile=header.profile, library=header.library)
        schemas = {sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()}
        channels = {cid: writer.register_channel(c.topic, c.message_encoding, schemas.get(c.schema_id, 0), c.metadata)
                    for cid, c in summary.channels.items()}
        for m in reader.iter_metadata():
            writer.add_metadata(m.name, dict(m.metadata))
        for a in reader.iter_attachments():
            writer.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        for _, channel, message in reader.iter_messages(log_time_order=False):
            data = message.data
            if channel.message_encoding in BUS_ENCODINGS:
                forces += channel.topic == "force"
                if spoil == "all" or (channel.topic == "force" and forces in spoil):
                    data = data[:-5]
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time, message.sequence)
        writer.finish()
    return out


def test_refused_messages_are_counted_and_the_grasps_they_may_belong_to_flagged(recorded, tmp_path, capsys):
    # Force 1 comes before any grasp (no grasp's); force 3 is g0's second (conftest's publish_session).
    log = _spoiled(recorded, tmp_path / "spoiled.mcap", spoil={1, 3})
    out = tmp_path / "records"
    assert main(["export", str(log), "--out", str(out), "--json"]) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out.strip().splitlines()[-1])
    assert report["refused"] == {"corrupt": 2} and report["complete"] is False and report["error"] is None
    written = {w["grasp_id"]: (w["complete"], w["refused"]) for w in report["written"]}
    assert written == {"g0": (False, 1), "g1": (True, 0)}
    assert "2 stored messages refused (2 corrupt), 1 records may miss data" in captured.err
    assert "incomplete grasp g0" in captured.err and "incomplete grasp g1" not in captured.err
    g0, g1 = (read_record(next(out.glob(f"*_{gid}.grasp"))) for gid in ("g0", "g1"))
    assert g0.provenance.extra["refused_messages"] == 1 and "refused_messages" not in g1.provenance.extra
    assert len(g0.force_n.t_s) == 9  # 3 of its 4 force messages of 3 samples


def test_a_log_whose_every_message_is_refused_says_so(recorded, tmp_path, capsys):
    log = _spoiled(recorded, tmp_path / "refused.mcap", spoil="all")
    assert main(["export", str(log), "--out", str(tmp_path / "records"), "--json"]) == 1
    captured = capsys.readouterr()
    report = json.loads(captured.out.strip().splitlines()[-1])
    assert set(report["refused"]) == {"corrupt"} and report["exported"] == 0
    count = report["refused"]["corrupt"]
    assert report["error"] == (f"no grasp record exported: no grasp event, frame, force or width message of {log} "
                               f"could be read: {count} stored messages refused ({count} corrupt)")
    assert "no grasp_event start/end" not in captured.err
