"""Audit of the display backend (:mod:`haptics.inputs.display`): a reconnection starts safe, every report
that has arrived is drained, a read waits only for the first report ever, and a connect that fails on
its first reports lets the link go (on the fake display of conftest and an injected clock)."""

from __future__ import annotations

import pytest

from haptics.errors import ProtocolError
from haptics.inputs.display import DisplayInput


def test_a_reconnected_display_reads_released_and_lost_until_it_reports_again(make_grip_display):
    display = make_grip_display()
    now = [5.0]
    device = DisplayInput(display, clock=lambda: now[0]).connect()
    display.push(0.7, enable=True)
    assert device.read().enable is True
    device.close()
    device.connect()  # no time has passed: the report from before the close must not count
    reading = device.read()
    assert reading.enable is False and reading.lost and reading.grip == 0.0
    device.close()


def test_a_report_exactly_stale_s_old_still_holds_the_enable(make_grip_display):
    display = make_grip_display()
    now = [1.0]
    with DisplayInput(display, stale_s=0.5, clock=lambda: now[0]) as device:
        display.push(0.4, enable=True)
        assert device.read().enable is True
        now[0] = 1.5
        reading = device.read()
        assert reading.enable is True and not reading.lost


def test_reports_handed_over_one_at_a_time_are_all_drained(make_grip_display):
    class OneAtATime(make_grip_display):
        def read_operator_reports(self, *, timeout_s: float):
            reports = super().read_operator_reports(timeout_s=timeout_s)
            self.reports.extendleft(reversed(reports[1:]))  # keep the rest for the next call
            return reports[:1]

    display = OneAtATime()
    with DisplayInput(display) as device:
        display.push(0.1, enable=False)
        display.push(0.2, enable=True, buttons=("next",))
        display.push(0.3, enable=True)
        reading = device.read()
        assert (reading.grip, reading.enable, reading.buttons) == (0.3, True, {"next"})


def test_after_the_first_report_a_read_takes_what_has_arrived_without_waiting(make_grip_display):
    class Recording(make_grip_display):
        def __init__(self) -> None:
            super().__init__()
            self.timeouts: list[float] = []

        def read_operator_reports(self, *, timeout_s: float):
            self.timeouts.append(timeout_s)
            return super().read_operator_reports(timeout_s=timeout_s)

    display = Recording()
    with DisplayInput(display) as device:
        display.push(0.4, enable=True)
        device.read(timeout_s=0.05)
        display.timeouts.clear()
        assert device.read(timeout_s=0.3).grip == 0.4
        assert display.timeouts and set(display.timeouts) == {0.0}


def test_a_connect_whose_first_reports_fail_lets_the_display_go_again(make_grip_display):
    class GarbledFirst(make_grip_display):
        def read_operator_reports(self, *, timeout_s: float):
            raise ProtocolError("grip report: bad crc")

    display = GarbledFirst()
    device = DisplayInput(display)
    with pytest.raises(ProtocolError, match="bad crc"):
        device.connect()
    assert not device.connected and not display.connected and display.closes == 1
