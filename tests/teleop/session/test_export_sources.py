"""Export: a grasp's events count from the publisher of its start, not from the estimator's forwarded ends."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from teleop.bus.wire import make_message
from teleop.record import GRASP_DONE_EVENT
from teleop.session.export import _Assembler
from teleop.settings import load_settings


def _message(source: str, kind: str, at_s: float, **body):
    return dataclasses.replace(make_message(kind, t_capture_s=at_s, **body), source=source)


def _grasp_data(grasp_id: str, t0: float) -> list:
    image = np.full((20, 30, 3), 7, np.uint8)
    return [
        _message("robot", "frame", t0 + 0.1, grasp_id=grasp_id, finger="left", index=0, encoding="raw",
                 data=image),
        _message("robot", "force", t0 + 0.2, grasp_id=grasp_id, t_s=[t0 + 0.15, t0 + 0.2], value_n=[1.0, 2.0]),
        _message("robot", "width", t0 + 0.2, grasp_id=grasp_id, t_s=[t0 + 0.2], value_m=[0.04]),
    ]


def test_a_grasp_a_restarted_node_started_again_ends_at_the_robots_end():
    # The robot node dies mid-grasp and, restarted, names the grasp again; the estimator's forwarded
    # end of the first comes before the robot's end of the second, and its own after it.
    assembler = _Assembler(path=Path("s.mcap"), settings=load_settings(), objects={}, source="simulated",
                           session_version="0", session="s", calibration_files={})
    messages = [
        _message("robot", "grasp_event", 1.0, event="start", grasp_id="x"),
        *_grasp_data("x", 1.0),
        _message("robot", "grasp_event", 10.0, event="start", grasp_id="x"),
        _message("estimator", "grasp_event", 10.0, event="end", grasp_id="x"),
        *_grasp_data("x", 10.0),
        _message("robot", "grasp_event", 11.0, event="end", grasp_id="x"),
        _message("estimator", "grasp_event", 11.0, event="end", grasp_id="x"),
    ]
    first, second = [grasp for message in messages for grasp in assembler.feed(message)]
    assert not first and "started again before it ended" in first.reason
    assert second, second.reason
    record = second.record
    assert record.events["grasp_start"] == 10.0 and record.events["grasp_end"] == 11.0
    assert np.array_equal(record.stream("left").t_s, [10.1])
    assert not assembler.open and not list(assembler.unfinished())


def test_an_end_from_another_publisher_neither_ends_nor_warns(caplog):
    assembler = _Assembler(path=Path("s.mcap"), settings=load_settings(), objects={}, source="simulated",
                           session_version="0", session="s", calibration_files={})
    messages = [_message("robot", "grasp_event", 1.0, event="start", grasp_id="x"), *_grasp_data("x", 1.0),
                _message("estimator", "grasp_event", 2.0, event="end", grasp_id="x")]
    assert [grasp for message in messages for grasp in assembler.feed(message)] == []
    assert list(assembler.open) == ["x"] and "never started" not in caplog.text
    # Its node went silent: the log goes on, so "the log stops before the grasp's end" would be untrue.
    (unfinished,) = assembler.unfinished()
    assert not unfinished and unfinished.reason == (
        "its publisher 'robot' never ended it (the estimator did: the robot node restarted or went silent "
        "during the grasp)")


def test_untagged_data_captured_before_the_start_is_dropped_and_counted():
    # A camera that delivers late: right frames captured before x started arrive, untagged, while x is
    # the only grasp open; the node leaves untagged only what it captured before the start.
    assembler = _Assembler(path=Path("s.mcap"), settings=load_settings(), objects={}, source="simulated",
                           session_version="0", session="s", calibration_files={})
    image = np.full((20, 30, 3), 7, np.uint8)

    def right(at_s):
        return _message("robot", "frame", at_s, grasp_id=None, finger="right", index=0, encoding="raw", data=image)

    messages = [
        _message("robot", "grasp_event", 10.0, event="start", grasp_id="x"),
        right(2.0), right(9.99),  # before the start: not x's
        _message("robot", "force", 9.95, t_s=[9.9, 9.95], value_n=[0.0, 0.0]),
        right(10.0), right(10.2),  # at and after the start: x's
        *_grasp_data("x", 10.0),
        _message("robot", "grasp_event", 11.0, event="end", grasp_id="x"),
    ]
    (grasp,) = [grasp for message in messages for grasp in assembler.feed(message)]
    assert grasp, grasp.reason
    assert np.array_equal(grasp.record.stream("right").t_s, [10.0, 10.2])
    assert np.array_equal(grasp.record.force_n.t_s, [10.15, 10.2])
    assert grasp.dropped == {"frame/right": 2, "force": 1}


def test_a_grasp_the_estimator_ended_in_a_log_cut_short_is_not_blamed_on_the_damage():
    # The robot node restarted mid-grasp (the estimator ended it) and, later, the recorder was killed:
    # the log stops at damage, but after the grasp the estimator ended; one it did not end is the damage's.
    cut = SimpleNamespace(stopped=True, damage="the file ends inside a chunk", lost=[])
    assembler = _Assembler(path=Path("s.mcap"), settings=load_settings(), objects={}, source="simulated",
                           session_version="0", session="s", calibration_files={}, reader=cut)
    messages = [_message("robot", "grasp_event", 1.0, event="start", grasp_id="x"), *_grasp_data("x", 1.0),
                _message("estimator", "grasp_event", 2.0, event="end", grasp_id="x"),
                _message("robot", "grasp_event", 3.0, event="start", grasp_id="y"), *_grasp_data("y", 3.0)]
    assert [grasp for message in messages for grasp in assembler.feed(message)] == []
    x, y = assembler.unfinished()
    assert x.reason == ("its publisher 'robot' never ended it (the estimator did: the robot node restarted or "
                        "went silent during the grasp)")
    assert y.reason == "the log stops at damage before the grasp's end event (the file ends inside a chunk)"


def test_a_loading_end_marker_keeps_the_grasp_open_and_becomes_its_grasp_done_event():
    # The robot marks where the loading phase ends; the hold and release after it are the same grasp's.
    assembler = _Assembler(path=Path("s.mcap"), settings=load_settings(), objects={}, source="simulated",
                           session_version="0", session="s", calibration_files={})
    messages = [_message("robot", "grasp_event", 1.0, event="start", grasp_id="x"),
                _message("robot", "grasp_event", 1.05, event="loading_end", grasp_id="x"),
                *_grasp_data("x", 1.0),
                _message("robot", "grasp_event", 2.0, event="end", grasp_id="x")]
    (grasp,) = [grasp for message in messages for grasp in assembler.feed(message)]
    assert grasp, grasp.reason
    assert grasp.record.events == {"grasp_start": 1.0, "grasp_end": 2.0, GRASP_DONE_EVENT: 1.05}
    assert np.array_equal(grasp.record.force_n.t_s, [1.15, 1.2])


def test_untagged_data_while_two_grasps_are_open_goes_to_neither():
    # Whose it is cannot be told: it is counted outside any grasp (module notes: "the only grasp open").
    assembler = _Assembler(path=Path("s.mcap"), settings=load_settings(), objects={}, source="simulated",
                           session_version="0", session="s", calibration_files={})
    messages = [_message("robot", "grasp_event", 1.0, event="start", grasp_id="x"),
                _message("robot", "grasp_event", 1.5, event="start", grasp_id="y"),
                _message("robot", "force", 2.0, t_s=[1.9, 2.0], value_n=[3.0, 3.0])]
    assert [grasp for message in messages for grasp in assembler.feed(message)] == []
    assert assembler.unassigned == 1
    assert not assembler.open["x"].force and not assembler.open["y"].force
