"""A display whose watchdog is not longer than the keep-alive (set longer, or left for later, never an
error out of a tick), and the reconnection log of a display that stays away (not a line per try)."""

from __future__ import annotations

import logging
from dataclasses import replace

import pytest

from haptics import renderer as renderer_module
from haptics.devices import Reconnector
from haptics.devices.sim import DisplayFirmware, SimulatedDisplay
from haptics.mapping import EstimateUpdate, stiffness_fraction
from haptics.protocol import DisplayInfo, decode_output_report
from haptics.renderer import HapticRenderer
from haptics.settings import DisplaySettings

SETTINGS = DisplaySettings(
    e_soft_pa=5e3, e_rigid_pa=1e9, smoothing_s=0.0, fade_s=0.3, stale_after_s=1.0, keepalive_s=0.2
)


def estimate(e_pa=1e6, *, grasp="g1"):
    return EstimateUpdate(e_pa, (None, None), "ok", "", False, grasp, 0.0)


def written(display: SimulatedDisplay) -> list:
    return [decode_output_report(data).command for kind, data in display.log if kind == "output"]


def short_watchdog(watchdog_ms=150) -> SimulatedDisplay:
    return SimulatedDisplay(firmware=DisplayFirmware(DisplayInfo(4095, watchdog_ms=watchdog_ms)))


class StubbornFirmware(DisplayFirmware):
    """Firmware that ignores a FEATURE SET: its watchdog cannot be changed."""

    def receive_feature(self, report: bytes) -> None:
        pass


def warnings_of(caplog, logger: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == logger and r.levelno == logging.WARNING]


@pytest.mark.parametrize(("keepalive_s", "watchdog_ms"), [
    (0.2, 400), (0.001, 2), (0.5, 1000), (0.6, 1200), (1.0, 2000), (1.0001, 2001), (60.0, 0xFFFF),
])
def test_the_watchdog_set_is_twice_the_keep_alive(keepalive_s, watchdog_ms):
    assert renderer_module.watchdog_for(keepalive_s) == watchdog_ms > keepalive_s * 1e3


def test_a_short_watchdog_met_at_the_first_connect_is_set_longer(caplog):
    display = short_watchdog(150)
    renderer = HapticRenderer(display, SETTINGS)
    with caplog.at_level(logging.WARNING):
        assert renderer.tick(0.0).level == 0
        renderer.on_estimate(estimate(1e6), 0.1)
    assert display.info.watchdog_ms == display.firmware.info.watchdog_ms == 400
    (message,) = warnings_of(caplog, "haptics.renderer")
    assert "simulated display" in message and "watchdog_ms = 150 ms" in message
    assert "keepalive_s = 0.2 s" in message and "400 ms" in message
    assert written(display)[-1].level == round(stiffness_fraction(1e6, e_soft_pa=5e3, e_rigid_pa=1e9) * 4095)


def test_a_display_swapped_for_one_with_a_short_watchdog_is_set_longer_and_rendering_goes_on(caplog):
    display = SimulatedDisplay()  # 1000 ms
    renderer = HapticRenderer(display, SETTINGS, reconnect_initial_s=0.05)
    renderer.on_estimate(estimate(1e6), 0.0)
    held = renderer.command
    display.unplug()
    display.firmware.info = replace(display.firmware.info, watchdog_ms=150)  # another unit
    display.replug()
    display.unplug()  # the write fails: the link is down
    with caplog.at_level(logging.WARNING):
        for i in range(1, 30):
            if i == 5:
                display.replug()
            renderer.tick(i * 0.05)  # never raises
    assert display.connected and display.info.watchdog_ms == 400
    assert renderer.stats.connects == 2 and written(display)[-1] == held
    assert len(warnings_of(caplog, "haptics.renderer")) == 2  # the failed write, and the watchdog once


def test_an_already_connected_display_with_a_short_watchdog_is_set_longer():
    display = short_watchdog(200)  # equal to keepalive_s: not longer
    display.connect()
    renderer = HapticRenderer(display, SETTINGS)
    assert renderer.tick(0.0).level == 0
    assert display.connected and display.info.watchdog_ms == 400


def test_a_display_that_keeps_its_short_watchdog_is_not_used_and_retried_with_backoff(caplog):
    display = SimulatedDisplay(firmware=StubbornFirmware(DisplayInfo(4095, watchdog_ms=150)))
    renderer = HapticRenderer(display, SETTINGS, reconnect_initial_s=0.05, reconnect_max_s=0.4)
    with caplog.at_level(logging.INFO):
        renderer.tick(0.0)  # no DisplayError out of a tick
        renderer.on_estimate(estimate(1e6), 0.01)
        for i in range(1, 101):
            renderer.tick(i * 0.01)
    assert not display.connected and written(display) == []  # nothing it would drop
    assert renderer.command.level > 0  # the command is still worked out
    attempts = sum(kind == "feature_set" for kind, _ in display.log)
    assert 2 <= attempts <= 6  # at 0, 0.05, 0.15, 0.35, 0.75: backoff, not every tick
    failures = warnings_of(caplog, "haptics.devices.base")
    assert len(failures) == 1 and "kept watchdog_ms = 150" in failures[0]
    assert "not longer than [display] keepalive_s = 0.2 s" in failures[0]
    # A display that takes the watchdog is used at the next try.
    display.firmware.__class__ = DisplayFirmware
    with caplog.at_level(logging.INFO):
        for i in range(101, 160):
            renderer.tick(i * 0.01)
    assert display.connected and display.info.watchdog_ms == 400 and written(display)
    back = [r for r in caplog.records if r.name == "haptics.devices.base" and "back after" in r.getMessage()]
    assert len(back) == 1 and back[0].levelno == logging.INFO


def test_a_display_that_stays_away_is_logged_at_the_first_tenth_and_hundredth_failure(caplog):
    display = SimulatedDisplay()
    display.unplug()
    reconnector = Reconnector(display, initial_s=0.05, max_s=2.0)
    now_s = 0.0
    with caplog.at_level(logging.INFO, logger="haptics.devices.base"):
        for _ in range(150):
            assert not reconnector.poll(now_s)
            now_s = reconnector.next_attempt_s
        assert reconnector.failures == 150
        display.replug()
        assert reconnector.poll(now_s)
    failed = warnings_of(caplog, "haptics.devices.base")
    assert len(failed) == 3 and all("reconnect failed" in m for m in failed)
    assert ["failure 1 in" in failed[0], "failure 10 in" in failed[1], "failure 100 in" in failed[2]] == [True] * 3
    infos = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO and "back after" in r.getMessage()]
    assert infos == ["simulated display: back after 150 failed reconnect attempt(s)"]
    assert reconnector.failures == 0
