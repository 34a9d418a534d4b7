"""The estimator service's check of each message's capture times (estimator.capture_times.check_times): a topic's
times go strictly forward from its last batch's newest, without a jump past MAX_CLOCK_JUMP_S; its first lies
within that of the grasp's newest capture time, another topic's included."""

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
