"""The estimator service's check of each message's capture times (estimator.capture_times.check_times): a topic's
times go strictly forward from its last batch's newest, without a jump past MAX_CLOCK_JUMP_S; its first lies
within that of the grasp's newest capture time, another topic's included.

Where it draws its lines: a repeated time is out of order, a step or a first time of exactly
MAX_CLOCK_JUMP_S (10 s) is a working clock and more is not, either side of the grasp's newest time; a
topic's first batch is judged by its first time against the grasp's start or a later time; a frame is
judged by its one capture time, per finger; a refusal names the last time."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from estimator.capture_times import MAX_CLOCK_JUMP_S, check_times
from estimator.errors import PerceptionError
from teleop.bus.wire import make_message


def _grasp(t_start_s: float = 0.0) -> SimpleNamespace:
    """What check_times reads of the service's open grasp."""
    return SimpleNamespace(grasp_id="g", t_start_s=t_start_s, last_t_s={})


def _force(*t_s: float):
    return make_message("force", t_capture_s=t_s[-1], grasp_id="g", t_s=np.array(t_s), value_n=np.zeros(len(t_s)))


def _width(*t_s: float):
    return make_message("width", t_capture_s=t_s[-1], grasp_id="g", t_s=np.array(t_s), value_m=np.zeros(len(t_s)))


def test_a_batch_not_after_the_newest_of_the_last_one_is_out_of_order():
    grasp = _grasp()
    check_times(grasp, _force(1.0, 1.1, 1.2))
    assert grasp.last_t_s["force"] == 1.2
    with pytest.raises(PerceptionError, match="out of order or repeated") as info:
        check_times(grasp, _force(1.15))  # after the last batch's first sample, before its newest
    assert info.value.reason == "out_of_order"
    check_times(grasp, _force(1.25))
    assert grasp.last_t_s["force"] == 1.25


def test_a_topics_first_time_is_judged_against_the_grasps_newest_time():
    step = 0.8 * MAX_CLOCK_JUMP_S
    grasp = _grasp(t_start_s=0.0)
    check_times(grasp, _force(step))
    check_times(grasp, _force(2 * step))  # a long grasp: the force ran on well past the start
    check_times(grasp, _width(2 * step + 0.5))  # far from the start, close to the force: a working clock
    assert grasp.last_t_s == {"force": 2 * step, "width": 2 * step + 0.5}
    with pytest.raises(PerceptionError, match="from the grasp's newest capture time") as info:
        check_times(_grasp(t_start_s=0.0), _width(2 * step + 0.5))  # with nothing newer than the start: far off
    assert info.value.reason == "far_from_grasp"


def test_a_jump_past_the_limit_is_a_broken_clock_within_a_batch_or_between_batches():
    grasp = _grasp()
    check_times(grasp, _force(1.0))
    for message in (_force(1.0 + MAX_CLOCK_JUMP_S + 1.0), _force(1.1, 1.1 + MAX_CLOCK_JUMP_S + 1.0)):
        with pytest.raises(PerceptionError, match="the capture clock is broken") as info:
            check_times(grasp, message)
        assert info.value.reason == "clock_jump"
    assert grasp.last_t_s["force"] == 1.0  # a refused batch is not remembered
    check_times(grasp, _force(1.0 + MAX_CLOCK_JUMP_S - 1.0))


def _frame(finger: str, t_s: float, index: int = 0):
    return make_message("frame", t_capture_s=t_s, grasp_id="g", finger=finger, index=index, encoding="jpeg",
                        data=b"\xff\xd8 not decoded here")


def _refused(grasp, message) -> PerceptionError:
    with pytest.raises(PerceptionError) as info:
        check_times(grasp, message)
    return info.value


def test_the_limit_is_ten_seconds():
    assert MAX_CLOCK_JUMP_S == 10.0
    grasp = _grasp()
    check_times(grasp, _force(1.0))
    assert _refused(grasp, _force(11.5)).reason == "clock_jump"


def test_a_repeated_time_is_out_of_order_within_a_batch_or_after_the_last():
    grasp = _grasp()
    assert _refused(grasp, _force(1.0, 1.0)).reason == "out_of_order"
    check_times(grasp, _force(1.0, 1.1))
    error = _refused(grasp, _force(1.1, 1.2))
    assert error.reason == "out_of_order" and "not after the previous one (1.100000 s)" in str(error)


def test_a_step_of_exactly_the_limit_is_a_working_clock():
    grasp = _grasp()
    check_times(grasp, _force(1.0))
    check_times(grasp, _force(1.0 + MAX_CLOCK_JUMP_S))
    check_times(grasp, _force(12.0, 12.0 + MAX_CLOCK_JUMP_S))
    assert grasp.last_t_s["force"] == 22.0


def test_a_first_time_exactly_the_limit_from_the_grasps_start_either_side_is_a_working_clock():
    check_times(_grasp(t_start_s=20.0), _force(20.0 + MAX_CLOCK_JUMP_S))
    check_times(_grasp(t_start_s=20.0), _force(20.0 - MAX_CLOCK_JUMP_S))


def test_a_first_time_well_before_the_grasps_start_is_a_broken_clock():
    error = _refused(_grasp(t_start_s=20.0), _force(20.0 - MAX_CLOCK_JUMP_S - 1.0))
    assert error.reason == "far_from_grasp" and "-11 s from the grasp's newest capture time" in str(error)


def test_a_topics_first_batch_is_judged_by_its_first_time():
    # From 10.5 s before the start to the start in steps of 5.5 s and 5 s: its first time is far from the grasp.
    grasp = _grasp(t_start_s=0.0)
    assert _refused(grasp, _force(-10.5, -5.0, 0.0)).reason == "far_from_grasp"
    assert grasp.last_t_s == {}


def test_another_topics_times_before_the_start_leave_the_start_the_newest():
    grasp = _grasp(t_start_s=20.0)
    check_times(grasp, _force(12.0))  # within the limit of the start, before it
    check_times(grasp, _width(29.0))  # 9 s from the start, 17 s from the force's: the start is the newest
    assert grasp.last_t_s == {"force": 12.0, "width": 29.0}


def test_a_frame_is_judged_by_its_capture_time_per_finger():
    grasp = _grasp(t_start_s=0.0)
    check_times(grasp, _frame("left", 1.0))
    check_times(grasp, _frame("right", 1.0))  # another finger's topic: the same time is no repeat
    check_times(grasp, _frame("left", 1.05, 1))
    assert grasp.last_t_s == {"frame/left": 1.05, "frame/right": 1.0}
    assert _refused(grasp, _frame("left", 1.05, 2)).reason == "out_of_order"
    assert _refused(grasp, _frame("right", 1.0 + MAX_CLOCK_JUMP_S + 0.5, 1)).reason == "clock_jump"
