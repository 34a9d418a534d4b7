"""teleop.live: the loop's duration, its end, the stop signals' handlers and the JSON-lines report."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import threading
import types

import pytest

from teleop.errors import SettingsError
from teleop.live import (
    JsonLines,
    ServiceLoop,
    StopSignals,
    bus_from_args,
    check_duration_s,
    sigint_ignored,
)
from teleop.settings import load_settings


class _Ticking(ServiceLoop):
    """A loop on a clock that reads one second later at every look."""

    def __init__(self) -> None:
        self.now, self.stats, self.finished = -1.0, 0, False

    def clock(self) -> float:
        self.now += 1.0
        return self.now

    def step(self) -> None:
        self.stats += 1

    def finish(self) -> None:
        self.finished = True


@pytest.mark.parametrize("duration_s", [True, "1", [1.0]])
def test_a_duration_that_is_no_number_is_refused(duration_s):
    with pytest.raises(ValueError, match=r"duration_s = .*: expected a finite number of seconds >= 0"):
        check_duration_s(duration_s)


def test_a_duration_is_refused_with_the_error_the_caller_names():
    with pytest.raises(SettingsError, match="duration_s = -0.5"):
        check_duration_s(-0.5, SettingsError)


@pytest.mark.parametrize("duration_s", [None, 0, 0.0, 2, 1e-9])
def test_no_duration_or_a_finite_one_of_zero_or_more_is_taken(duration_s):
    check_duration_s(duration_s)


def test_a_loop_steps_until_its_duration_passed_not_a_step_more_and_then_finishes():
    loop = _Ticking()
    assert loop.run(threading.Event(), duration_s=3.0) == 2  # steps at t = 1 and 2; t = 3 is the deadline
    assert loop.finished


def test_a_loop_of_no_duration_takes_no_step_but_finishes():
    loop = _Ticking()
    assert loop.run(threading.Event(), duration_s=0) == 0 and loop.finished


def test_a_stopped_loop_takes_no_step_and_finishes():
    loop, stop = _Ticking(), threading.Event()
    stop.set()
    assert loop.run(stop) == 0 and loop.finished


def test_stop_signals_restore_the_handlers_they_replaced():
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    with StopSignals() as signals:
        assert all(signal.getsignal(s) == signals._handle for s in before)
    assert {s: signal.getsignal(s) for s in before} == before


def test_sigint_ignored_ignores_the_stop_signals_when_asked_and_restores_them():
    names = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    before = {s: signal.getsignal(s) for s in names}
    with sigint_ignored():
        assert [signal.getsignal(s) is signal.SIG_IGN for s in names] == [True, False, before[signal.SIGHUP]
                                                                          is signal.SIG_IGN]
    with sigint_ignored(stop_signals=True):
        assert all(signal.getsignal(s) is signal.SIG_IGN for s in names)
    assert {s: signal.getsignal(s) for s in names} == before


def test_sigint_ignored_outside_the_main_thread_is_a_no_op():
    done: list[object] = []

    def target():
        try:
            with sigint_ignored(stop_signals=True):
                done.append("ran")
        except ValueError as exc:  # signal.signal outside the main thread
            done.append(exc)

    thread = threading.Thread(target=target)
    thread.start()
    thread.join(timeout=30)
    assert done == ["ran"]


def test_a_report_refuses_a_nan_rather_than_write_json_no_reader_takes(tmp_path, caplog):
    path = tmp_path / "report.jsonl"
    with JsonLines(path) as report:
        report.write({"e_pa": 1.0})
        with pytest.raises(ValueError, match="not JSON compliant"):
            report.write({"e_pa": math.nan})
    assert path.read_text() == '{"e_pa": 1.0}\n'


def test_a_report_appends_to_the_records_already_there(tmp_path):
    path = tmp_path / "report.jsonl"
    path.write_text('{"run": 1}\n')
    with JsonLines(path) as report:
        report.write({"run": 2})
        assert path.read_text() == '{"run": 1}\n{"run": 2}\n'  # flushed as written
    assert path.read_text() == '{"run": 1}\n{"run": 2}\n'


def test_a_report_on_a_line_cut_short_starts_on_a_new_line(tmp_path):
    path = tmp_path / "report.jsonl"
    path.write_text('{"run": 1}\n{"ru')
    with JsonLines(path) as report:
        report.write({"run": 2})
    assert path.read_text().splitlines() == ['{"run": 1}', '{"ru', '{"run": 2}']


def test_a_report_that_cannot_be_opened_is_a_settings_error_naming_it(tmp_path):
    with pytest.raises(SettingsError, match="cannot open report file .*missing"):
        JsonLines(tmp_path / "missing" / "report.jsonl")


def test_no_report_path_writes_nothing():
    with JsonLines(None) as report:
        report.write({"x": 1})
    assert report.path is None


def test_endpoints_not_given_on_the_command_line_keep_the_settings():
    settings = load_settings()
    args = argparse.Namespace(bus_robot_pub=None, bus_command="")
    assert bus_from_args(settings, args) == settings.bus


def test_a_report_to_a_named_pipe_is_written_not_refused_for_its_position(tmp_path):
    fifo = tmp_path / "report.fifo"
    os.mkfifo(fifo)
    received: list[bytes] = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()), daemon=True)
    reader.start()
    try:
        with JsonLines(fifo) as report:
            report.write({"grasp_id": "g1"})
    finally:
        if reader.is_alive() and not received:
            with contextlib.suppress(OSError), open(fifo, "wb", buffering=0):  # unblock the reader
                pass
    reader.join(timeout=30)
    assert received == [b'{"grasp_id": "g1"}\n']


def test_wire_stats_give_each_subscriber_the_service_has():
    stats = types.SimpleNamespace(received=5, refused={"schema": 1}, gaps=2, missed=3, restarts=0)
    loop = _Ticking()
    assert loop.wire_stats() == {}
    loop.commands = types.SimpleNamespace(stats=stats)
    assert loop.wire_stats() == {"commands": {"received": 5, "refused": {"schema": 1}, "gaps": 2, "missed": 3,
                                              "restarts": 0}}
    loop.subscriber = types.SimpleNamespace(stats=stats)
    assert set(loop.wire_stats()) == {"subscriber", "commands"}
