"""The long-running processes' shared loop."""

from __future__ import annotations

import math
import threading

import pytest

from teleop.live import ServiceLoop


class _Counting(ServiceLoop):
    def __init__(self) -> None:
        self.clock, self.stats = (lambda: 0.0), 0

    def step(self) -> None:
        self.stats += 1


@pytest.mark.parametrize("duration_s", [math.nan, math.inf, -1.0])
def test_a_duration_that_is_no_time_is_refused_before_a_step(duration_s):
    loop = _Counting()
    with pytest.raises(ValueError, match=r"duration_s = .*: expected a finite number of seconds >= 0"):
        loop.run(threading.Event(), duration_s=duration_s)
    assert loop.stats == 0
