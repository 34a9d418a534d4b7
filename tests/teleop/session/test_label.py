"""``teleop label``: labels from a CSV written into a session log, every original record kept."""

from __future__ import annotations

import dataclasses
import json
import shutil
import struct

import pytest
from mcap.reader import make_reader
from support.session_logs import write_log

import teleop.cli
import teleop.session.label as label_module
from teleop.bus.wire import make_message
from teleop.errors import SessionLogError
from teleop.labels import LabelError, gent_modulus_pa, shore_to_modulus_pa
from teleop.session import LogReader
from teleop.session.label import LABEL_SOURCE_NAME, LABELS_METADATA, label_session, read_label_csv

T0 = 1_700_000_000_000_000_000  # a log time (ns): 2023-11-14


@pytest.fixture
def log(recorded, tmp_path):
    """A copy of the recorded session (grasps g0 with stress_ball, g1 unnamed, g2 never ended)."""
    path = tmp_path / "session.mcap"
    shutil.copyfile(recorded.path, path)
    return path


def _csv(tmp_path, text: str, name: str = "labels.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _records(path):
    """Every stored message in file order: (topic, log time, publish time, sequence, data)."""
    with path.open("rb") as f:
        return [
            (channel.topic, m.log_time, m.publish_time, m.sequence, bytes(m.data))
            for _, channel, m in make_reader(f).iter_messages(log_time_order=False)
        ]


def _labels(path, *, log_time_order: bool = False):
    messages = [m for m in LogReader(path).messages(topics=("label",))]
    if log_time_order:
        messages.sort(key=lambda m: m.log_time_ns)
    return messages


def _last_per_grasp(messages):
    return {m.message.body["grasp_id"]: m.message.body for m in messages}


def test_labels_are_added_and_every_original_record_is_kept(recorded, log, tmp_path):
    before = _records(log)
    info_before = LogReader(log).info()
    events = {m.message.body["grasp_id"]: m for m in LogReader(log).messages(topics=("grasp_event",))}
    csv_path = _csv(tmp_path, "grasp_id,object,shore_00\ng0,stress_ball,\ng1,blue gel pad,60\n")

    report = label_session(log, csv_path)

    assert [b["grasp_id"] for b in report.labels] == ["g0", "g1"] and report.relabelled == []
    assert report.messages == len(before) and report.grasps == 3
    after = _records(log)
    # the original messages, byte for byte, in their order; each label (after its JSON form) right
    # after its grasp's end, so that the file stays in receive order
    added = [i for i, (topic, *_) in enumerate(after) if topic in ("/label", "label")]
    assert [r for i, r in enumerate(after) if i not in added] == before
    assert [after[i][0] for i in added] == ["/label", "label", "/label", "label"]
    for start, grasp_id in zip(added[::2], ("g0", "g1"), strict=True):
        end = events[grasp_id]
        assert after[start - 1][:2] == ("grasp_event", end.log_time_ns) and added[added.index(start) + 1] == start + 1
    info = LogReader(log).info()
    assert info.complete and info.attachments == info_before.attachments
    assert {k: v for k, v in info.metadata.items() if k != LABELS_METADATA} == info_before.metadata
    assert json.loads(info.metadata[LABELS_METADATA]["labels"]) == ["g0", "g1"]
    assert not list(tmp_path.glob("*.partial")) and not list(tmp_path.glob("*.bak"))

    labels = _labels(log)
    g0, g1 = (m.message for m in labels)
    assert g0.body == {"grasp_id": "g0", "object_name": "stress_ball", "modulus_pa": 4.0e4, "source": "catalogue",
                       "detail": g0.body["detail"]}
    assert "catalogue.toml" in g0.body["detail"]  # the catalogue attached to the log
    assert g1.body["source"] == "durometer" and g1.body["object_name"] == "blue gel pad"
    assert g1.body["modulus_pa"] == pytest.approx(shore_to_modulus_pa(60, "00"))
    assert "Shore 00 60" in g1.body["detail"]
    for logged, grasp_id in zip(labels, ("g0", "g1"), strict=True):
        end = events[grasp_id]
        assert logged.log_time_ns == end.log_time_ns + 1  # stamped just after the grasp's end
        assert logged.publish_time_ns == logged.log_time_ns
        assert logged.message.t_send_ns == logged.log_time_ns - info.offset_ns  # the monotonic clock, as sent
        assert logged.message.t_capture_s == end.message.t_capture_s
        assert logged.message.source == LABEL_SOURCE_NAME
    assert [m.message.seq for m in labels] == [0, 1]
    # every bus message still decodes: nothing refused
    reader = LogReader(log)
    assert sum(1 for _ in reader.messages()) == len(recorded.sent) + 2 and not reader.refused


def test_a_grasp_labelled_again_takes_the_newer_label(log, tmp_path):
    label_session(log, _csv(tmp_path, "grasp_id,object,shore_a\ng1,pad,40\n", "first.csv"))
    report = label_session(
        log, _csv(tmp_path, "grasp_id,object,modulus_pa,source\ng1,pad,2.5e6,measured\ng2,cork,1.2e7,\n", "second.csv")
    )
    assert report.relabelled == ["g1"]
    labels = _labels(log)
    assert len(labels) == 3 and [m.message.seq for m in labels] == [0, 1, 2]
    for order in (False, True):  # file order and log-time order agree
        last = _last_per_grasp(_labels(log, log_time_order=order))
        assert last["g1"]["modulus_pa"] == 2.5e6 and last["g1"]["source"] == "measured"
        assert last["g2"]["source"] == "datasheet"
    first, second = labels[0], labels[1]
    assert second.log_time_ns == first.log_time_ns + 1


def test_a_catalogue_can_be_given(log, tmp_path):
    catalogue = tmp_path / "lab.toml"
    catalogue.write_text('[[objects]]\nname = "lab_gel"\nshape = "box"\nmaterial = "rubber"\nmodulus_pa = 7.5e4\n')
    report = label_session(log, _csv(tmp_path, "grasp_id,object\ng0,lab_gel\n"), catalogue=catalogue)
    assert report.labels[0]["modulus_pa"] == 7.5e4 and str(catalogue) in report.labels[0]["detail"]


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("grasp_id,object\ng7,stress_ball\n", "grasp 'g7' is not in"),
        ("grasp_id,object\ng7,stress_ball\n", "the log's grasps are g0, g1, g2"),
        ("grasp_id,object\ng0,blue gel\n", "labels.csv:2 (grasp g0): object 'blue gel' is not in the log's catalogue.toml"),
        ("grasp_id,object,modulus_pa\ng0,pad,1.2 MPa\n", "modulus_pa '1.2 MPa' is not a number"),
        ("grasp_id,object,shore_a\ng0,pad,40\ng1,pad,120\n", "labels.csv:3 (grasp g1): Shore A 120 is outside 10 to 90"),
        ("grasp,object\ng0,pad\n", "missing grasp_id"),
        ("grasp_id,object,shore_d\ng0,pad,40\n", "unknown column(s) 'shore_d'"),
        ("grasp_id,object\n", "no label rows"),
        ("grasp_id,object\n,pad\n", "labels.csv:2: the grasp_id is empty"),
        ("grasp_id,object\ng1,pad_a\ng0,stress_ball\ng1,pad_b\n", "labels.csv:4: grasp 'g1' is also on line 2"),
    ],
)
def test_bad_input_is_refused_and_the_log_left_as_it_was(log, tmp_path, text, says):
    before = log.read_bytes()
    with pytest.raises(LabelError) as info:
        label_session(log, _csv(tmp_path, text))
    assert says in str(info.value)
    assert log.read_bytes() == before and not list(tmp_path.glob("*.partial"))


def test_every_refused_row_is_named_in_one_error(log, tmp_path):
    text = "grasp_id,object,modulus_pa\ng0,stress_ball,\ng7,pad,1e6\ng1,blue gel,\ng2,pad,-3\n"
    with pytest.raises(LabelError) as info:
        label_session(log, _csv(tmp_path, text))
    lines = str(info.value).splitlines()
    assert lines[0] == "3 rows are refused:"
    assert [line.split(":")[1].split()[0] for line in lines[1:4]] == ["3", "4", "5"]  # the CSV's lines, in order
    assert "grasp 'g7' is not in" in lines[1] and "'blue gel'" in lines[2] and "-3.0" in lines[3]
    assert lines[4].startswith("the log's grasps are g0, g1, g2")


def test_a_grasp_named_on_two_rows_is_refused_not_counted_as_relabelled(log, tmp_path, capsys):
    before = log.read_bytes()
    csv_path = _csv(tmp_path, "grasp_id,object,modulus_pa\ng0,stress_ball,\ng1,pad,1e6\ng1,pad,2e6\n")
    assert teleop.cli.main(["label", str(log), "--csv", str(csv_path)]) == 2
    err = capsys.readouterr().err
    assert "labels.csv:4: grasp 'g1' is also on line 3; give each grasp one row" in err
    assert "replaced the labels" not in err and log.read_bytes() == before


def test_a_cut_log_is_refused_with_the_way_out(log, tmp_path):
    data = log.read_bytes()
    log.write_bytes(data[: len(data) // 2])
    with pytest.raises(SessionLogError, match=r"is cut short .*`teleop recover .* --out FIXED.mcap`"):
        label_session(log, _csv(tmp_path, "grasp_id,object\ng0,stress_ball\n"))
    assert log.read_bytes() == data[: len(data) // 2]


def _garble_length(log, kind, name):
    """Give the ``kind`` record (attachment or metadata) ``name`` of ``log`` a length field past the
    end of the file, its summary and footer intact: reading skips it. Returns its offset."""
    data = bytearray(log.read_bytes())
    with log.open("rb") as f:
        summary = make_reader(f).get_summary()
    indexes = summary.attachment_indexes if kind == "attachment" else summary.metadata_indexes
    offset = next(index.offset for index in indexes if index.name == name)
    data[offset + 1 : offset + 9] = struct.pack("<Q", 2**40)
    log.write_bytes(bytes(data))
    return offset


@pytest.mark.parametrize("kind, name, record", [
    ("attachment", "calibration/left/left_cal.npz", "an attachment record"),
    ("metadata", "rig", "a metadata record"),
])
def test_a_log_that_lost_a_record_other_than_a_chunk_is_refused_not_labelled_whole(log, tmp_path, kind, name,
                                                                                   record):
    """The copy would leave the skipped record out and read as whole: the loss would be erased."""
    offset = _garble_length(log, kind, name)
    before = log.read_bytes()
    info = LogReader(log).info()
    assert info.damage and not info.mendable
    with pytest.raises(SessionLogError) as refused:
        label_session(log, _csv(tmp_path, "grasp_id,object\ng0,stress_ball\n"))
    said = str(refused.value)
    assert said.startswith(f"{log}: ") and f"{record} {name!r}" in said and f"after byte {offset}" in said
    assert f"`teleop recover {log} --out FIXED.mcap`" in said and "the log is unchanged" in said
    assert log.read_bytes() == before


def test_a_log_whose_session_end_record_is_damaged_is_refused_as_damaged(log, tmp_path):
    _garble_length(log, "metadata", "session_end")
    before = log.read_bytes()
    with pytest.raises(SessionLogError, match=r"cut short or damaged .*'session_end'.*`teleop recover"):
        label_session(log, _csv(tmp_path, "grasp_id,object\ng0,stress_ball\n"))
    assert log.read_bytes() == before


def test_a_grasp_that_never_ended_is_labelled_with_a_warning_that_export_skips_it(log, tmp_path, capsys):
    csv_path = _csv(tmp_path, "grasp_id,object\ng0,stress_ball\ng2,stress_ball\n")
    assert teleop.cli.main(["label", str(log), "--csv", str(csv_path), "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out.strip().splitlines()[-1])["unended"] == ["g2"]
    assert "warning: grasp g2 has no end event" in captured.err and "export` skips it" in captured.err
    assert "grasp g0 has no end" not in captured.err
    assert sorted(_last_per_grasp(_labels(log))) == ["g0", "g2"]  # written all the same


def test_the_command(log, tmp_path, capsys):
    csv_path = _csv(tmp_path, "grasp_id,object,shore_a\ng0,stress_ball,\ng1,pad,40\n")
    assert teleop.cli.main(["label", str(log), "--csv", str(csv_path), "--json"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out.strip().splitlines()[-1])
    assert [b["grasp_id"] for b in summary["labels"]] == ["g0", "g1"] and summary["grasps"] == 3
    assert summary["labels"][1]["modulus_pa"] == pytest.approx(gent_modulus_pa(40))
    assert "labelled 2 grasp(s) of 3" in captured.err and "g1: pad, E 1.69e+06 Pa (durometer)" in captured.err
    # an error is one line naming the input, no traceback
    assert teleop.cli.main(["label", str(log), "--csv", str(_csv(tmp_path, "grasp_id,object\nzz,pad\n", "b.csv"))]) == 2
    err = capsys.readouterr().err
    assert err.startswith("teleop label: error: ") and "b.csv:2" in err and "Traceback" not in err
    assert teleop.cli.main(["label", str(tmp_path / "missing.mcap"), "--csv", str(csv_path)]) == 2
    assert "cannot read session log" in capsys.readouterr().err


def test_a_csv_row_with_more_cells_than_columns_is_refused_naming_its_line(tmp_path):
    path = _csv(tmp_path, "grasp_id,object,modulus_pa\ng0,foam,50000\ng1,foam,5,0000\n")
    with pytest.raises(LabelError, match=r"labels\.csv:3: more cells than the header has columns"):
        read_label_csv(path)


def _event(event, grasp_id, source, seq):
    message = make_message("grasp_event", t_capture_s=1.0, event=event, grasp_id=grasp_id, object_name=None)
    return dataclasses.replace(message, source=source, seq=seq)


def test_an_end_from_another_publisher_does_not_end_the_grasp(tmp_path):
    log = write_log(tmp_path / "s.mcap", [
        (T0, _event("start", "g0", "robot", 0)),
        (T0 + 10, _event("end", "g0", "estimator", 0)),  # not the publisher of the start
        (T0 + 20, _event("start", "g1", "robot", 1)),
        (T0 + 30, _event("end", "g1", "robot", 2)),
    ])
    report = label_session(log, _csv(tmp_path, "grasp_id,object,modulus_pa\ng0,foam,50000\ng1,foam,50000\n"))
    assert report.unended == ["g0"]


def test_a_label_goes_after_the_last_event_of_its_grasp_at_equal_log_times(tmp_path):
    log = write_log(tmp_path / "s.mcap", [
        (T0, _event("start", "g0", "robot", 0)),
        (T0, _event("end", "g0", "robot", 1)),  # same log time: the later in the file is the newer
    ])
    label_session(log, _csv(tmp_path, "grasp_id,object,modulus_pa\ng0,foam,50000\n"))
    order = [(m.message.type, m.message.body.get("event"))
             for m in LogReader(log).messages(topics=("grasp_event", "label"))]
    assert order == [("grasp_event", "start"), ("grasp_event", "end"), ("label", None)]


def test_a_log_whose_grasp_event_is_gone_by_the_copy_is_refused_and_left_as_it_was(log, tmp_path, monkeypatch):
    before = log.read_bytes()
    survey = label_module._survey

    def moved(reader):  # as if the log changed between the survey and the copy
        grasps, seq = survey(reader)
        grasps["g0"].anchor = ("grasp_event", 1, 1)
        return grasps, seq

    monkeypatch.setattr(label_module, "_survey", moved)
    with pytest.raises(SessionLogError, match="changed while it was labelled"):
        label_session(log, _csv(tmp_path, "grasp_id,object\ng0,stress_ball\n"))
    assert log.read_bytes() == before


def test_a_log_cut_short_after_the_survey_is_refused_not_written_short(log, tmp_path, monkeypatch):
    survey = label_module._survey

    def cut_after(reader):  # the log is cut (another writer, a full disk) once it was surveyed
        surveyed = survey(reader)
        data = log.read_bytes()
        log.write_bytes(data[: len(data) - 200])
        return surveyed

    monkeypatch.setattr(label_module, "_survey", cut_after)
    with pytest.raises(SessionLogError, match="could not be read to its end"):
        label_session(log, _csv(tmp_path, "grasp_id,object\ng0,stress_ball\n"))


def test_the_recorder_logs_a_label_sent_at_capture(tmp_path, helpers, session_settings):
    """The console's label goes out on bus.command, which `teleop record` subscribes to (every topic)."""
    import argparse
    import dataclasses

    from haptics.operator_link import OperatorLink
    from teleop.session import record_cli

    parser = argparse.ArgumentParser()
    record_cli.add_arguments(parser)
    assert "bus.command" in parser.format_help().replace("\n", " ").replace("  ", " ")  # default endpoints
    bus = dataclasses.replace(session_settings.bus, command="tcp://127.0.0.1:*")
    path = tmp_path / "live.mcap"
    with (
        OperatorLink.from_settings(bus) as link,
        helpers.recording(path, [link.publisher.endpoint], settings=session_settings) as recorder,
    ):
        link.publisher.wait_for_subscriber("label")
        link.label("op-1", "stress_ball", modulus_pa=4e4, source="catalogue", detail="objects.toml")
        helpers.wait_for(lambda: recorder.stats.topics["label"] == 1, what="the label in the log")
    (logged,) = _labels(path)
    assert logged.message.source == "operator" and logged.message.body["object_name"] == "stress_ball"
    assert logged.message.body["modulus_pa"] == 4e4 and logged.message.body["source"] == "catalogue"
