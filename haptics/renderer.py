"""The haptic renderer: estimates in, display reports out, time driven by the caller.

No bus, no threads and no clock inside: the caller passes ``now_s`` (seconds
on one monotonic clock) to every method, so the whole behaviour is testable
step by step. A thin adapter feeds :meth:`HapticRenderer.on_estimate` from
the bus; anything else (a file replay, a test) can feed it the same way.

Phases: *idle* (free, nothing to render) -> *active* on the first estimate of
a grasp (smoothing toward the latest estimate; *stale* when, after a provisional
estimate, no estimate came for ``stale_after_s``: the last value is held and
flagged; a final estimate is the grasp's last and never goes stale) -> *fading* on the
grasp's end, or on :meth:`HapticRenderer.release` (linear fade to free over ``fade_s``)
-> idle. Estimates of a grasp that has ended, or that had its final estimate, are
ignored, so a late estimate cannot re-engage the display. A report is written when the command
changes, or every ``keepalive_s`` to feed the display's watchdog. A display whose
``watchdog_ms`` is nonzero and not longer than ``keepalive_s`` would go free while holding a
value: on connect and reconnect the renderer sets its watchdog (:meth:`SoftnessDisplay.configure`)
to :func:`watchdog_for` ``keepalive_s`` and logs it at warning; a display that refuses is
disconnected and retried later with the reconnection backoff, never an error out of a call.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Hashable
from dataclasses import dataclass

from haptics.devices.base import Reconnector, SoftnessDisplay
from haptics.errors import DisplayError, MappingError
from haptics.mapping import (
    FREE,
    EstimateUpdate,
    Percept,
    fade,
    fade_gain,
    is_stale,
    map_estimate,
    smooth,
    to_command,
)
from haptics.protocol import StiffnessCommand
from haptics.settings import DisplaySettings

__all__ = ["HapticRenderer", "RendererStats", "watchdog_for"]

log = logging.getLogger(__name__)

#: How many ended grasps are remembered to ignore their late estimates.
_ENDED_MEMORY = 16
#: The largest level_max a display can state: checks a command before the display is known.
_LEVEL_MAX = 0xFFFF
#: The largest watchdog_ms the FEATURE report carries (uint16).
_WATCHDOG_MAX_MS = 0xFFFF


def watchdog_for(keepalive_s: float) -> int:
    """The ``watchdog_ms`` set on a display whose watchdog is not longer than ``keepalive_s``.

    Twice the keep-alive (rounded up to a whole ms): one late or lost keep-alive does not free the
    display, and a host that is gone frees it soon. At most 65535 ms, the field's limit, which is
    still above any keepalive_s the settings allow (at most 60 s).
    """
    twice_ms = math.ceil(round(2e3 * keepalive_s, 6))  # the rounding drops float noise (0.2 * 2e3)
    return min(_WATCHDOG_MAX_MS, twice_ms)


@dataclass
class RendererStats:
    """Counters of one renderer.

    ``last_latency_s`` is the time from the capture of the data behind the
    latest estimate (its ``t_s``) to the first report written after it
    arrived, on the caller's clock; it is meaningful when ``now_s`` and the
    estimates' ``t_s`` share a clock.
    """

    estimates: int = 0
    estimates_ignored: int = 0
    reports_sent: int = 0
    write_failures: int = 0
    connects: int = 0
    last_latency_s: float | None = None


class HapticRenderer:
    """Maps a stream of estimates onto a softness display.

    Parameters
    ----------
    display : SoftnessDisplay
        Connected or not: the renderer connects it on the first call and
        reconnects it (with backoff, resending the last command) after an unplug.
    settings : DisplaySettings
        E range, smoothing, fade, staleness and keep-alive times. The range must be
        resolved: a bare ``DisplaySettings()`` has ``e_rigid_pa = 0`` ("the estimating
        sensor's resolution limit"), which only a full :class:`~teleop.settings.Settings`
        turns into a modulus; pass ``display_settings(load_settings(...))``.
    reconnect_initial_s, reconnect_max_s : float
        Backoff between reconnection attempts: doubling from the first to the second.

    Raises
    ------
    MappingError
        ``settings.e_rigid_pa`` is unresolved (0) or not above ``e_soft_pa``.
    """

    def __init__(
        self,
        display: SoftnessDisplay,
        settings: DisplaySettings,
        *,
        reconnect_initial_s: float = 0.05,
        reconnect_max_s: float = 2.0,
    ) -> None:
        if not settings.e_rigid_pa > settings.e_soft_pa:
            raise MappingError(
                f"DisplaySettings.e_rigid_pa = {settings.e_rigid_pa!r}: unresolved (0 stands for the "
                "estimating sensor's resolution limit, which only full settings know); render with "
                "display_settings(load_settings(...)), or set e_rigid_pa above e_soft_pa = "
                f"{settings.e_soft_pa!r}"
            )
        self.display = display
        self.settings = settings
        self.stats = RendererStats()
        self._reconnector = Reconnector(display, reconnect_initial_s, reconnect_max_s,
                                        accept=self._fit_watchdog)
        self._grasp_id: Hashable = None
        self._active = False
        self._ended: deque[Hashable] = deque(maxlen=_ENDED_MEMORY)
        self._target = FREE
        self._shown = FREE
        self._released = FREE
        self._release_s: float | None = None
        self._last_update_s = -math.inf
        self._expecting = False  # the last estimate was provisional: more are due
        self._last_tick_s: float | None = None
        self._last_written: StiffnessCommand | None = None
        self._last_write_s = -math.inf
        self._pending_t_s: float | None = None
        self._command: StiffnessCommand | None = None

    # ------------------------------------------------------------ state

    @property
    def phase(self) -> str:
        """``idle``, ``active``, ``stale`` or ``fading`` as of the last call."""
        if self._active:
            return "stale" if self._stale(self._last_tick_s) else "active"
        return "fading" if self._release_s is not None else "idle"

    @property
    def percept(self) -> Percept:
        """What is being rendered, before quantisation."""
        return self._shown

    @property
    def target(self) -> Percept:
        """What the latest estimate maps to: the percept the display is settling on
        (free once the grasp ended)."""
        return self._target

    @property
    def command(self) -> StiffnessCommand | None:
        """The command as of the last call (None before the display was ever connected)."""
        return self._command

    @property
    def grasp_id(self) -> Hashable:
        """The grasp being rendered, or None."""
        return self._grasp_id if self._active else None

    @property
    def has_final(self) -> bool:
        """Whether the grasp being rendered had its final estimate (only its end is due)."""
        return self._active and not self._expecting

    # ------------------------------------------------------------ inputs

    def on_estimate(self, update: EstimateUpdate, now_s: float) -> None:
        """Take one estimate received at ``now_s``.

        An estimate of a grasp that ended, or that already had its final estimate (the grasp's
        last), is ignored and counted in ``stats.estimates_ignored``. One that cannot be
        rendered raises before anything of it is taken.
        """
        self._advance(now_s)
        same_grasp = self._active and update.grasp_id == self._grasp_id
        if update.grasp_id in self._ended or (same_grasp and not self._expecting):
            self.stats.estimates_ignored += 1
            log.debug("ignoring an estimate of grasp %r: it ended or had its final estimate",
                      update.grasp_id)
            self._output(now_s)  # the command as of now_s, as after any call
            return
        target = map_estimate(
            update, e_soft_pa=self.settings.e_soft_pa, e_rigid_pa=self.settings.e_rigid_pa
        )
        # Flags change at once; the level starts its lag now (at once when smoothing_s is 0).
        shown = smooth(self._shown, target, dt_s=0.0, smoothing_s=self.settings.smoothing_s)
        # Quantise before taking it: one that cannot become a command changes nothing.
        info = self.display.info
        to_command(shown, level_max=_LEVEL_MAX if info is None else info.level_max)
        if not same_grasp:
            if self._active:  # a new grasp implies the old one is over
                self._ended.append(self._grasp_id)
            self._grasp_id, self._active, self._release_s = update.grasp_id, True, None
        self._target, self._shown = target, shown
        self._last_update_s, self._expecting = now_s, update.provisional
        self._pending_t_s = update.t_s
        self.stats.estimates += 1
        self._output(now_s)

    def on_grasp_end(self, grasp_id: Hashable, now_s: float) -> None:
        """The grasp ``grasp_id`` was released at ``now_s``: fade to free."""
        self._advance(now_s)
        if grasp_id not in self._ended:
            self._ended.append(grasp_id)
        if self._active and grasp_id == self._grasp_id:
            self._fade_out(now_s)
        self._output(now_s)

    def release(self, now_s: float) -> None:
        """Fade to free at ``now_s`` what is rendered, without ending its grasp: when no one vouches
        for the value held any more (its estimator is gone), though the grasp may go on. A later
        estimate of that grasp engages the display again, as a new grasp's would."""
        self._advance(now_s)
        if self._active:
            self._fade_out(now_s)
        self._output(now_s)

    def tick(self, now_s: float) -> StiffnessCommand | None:
        """Advance smoothing, staleness and fade to ``now_s``; write if due. Returns the command."""
        self._advance(now_s)
        self._output(now_s)
        return self._command

    # ------------------------------------------------------------ internals

    def _stale(self, now_s: float | None) -> bool:
        return (
            self._active
            and self._expecting
            and now_s is not None
            and is_stale(self._last_update_s, now_s, stale_after_s=self.settings.stale_after_s)
        )

    def _advance(self, now_s: float) -> None:
        if not math.isfinite(now_s):
            raise MappingError(f"now_s = {now_s!r}: expected a finite time in seconds")
        last = now_s if self._last_tick_s is None else self._last_tick_s
        if now_s < last:
            raise MappingError(f"now_s = {now_s!r}: before the previous call's {last!r}")
        self._last_tick_s = now_s
        if self._active:
            # Smoothing runs until the estimate goes stale; from then on the value is held.
            stale_at_s = self._last_update_s + self.settings.stale_after_s if self._expecting else math.inf
            dt_s = max(0.0, min(now_s, stale_at_s) - last)
            self._shown = smooth(
                self._shown, self._target, dt_s=dt_s, smoothing_s=self.settings.smoothing_s
            )
        elif self._release_s is not None:
            self._fade_to(now_s)

    def _fade_out(self, now_s: float) -> None:
        self._active = False
        self._release_s, self._released, self._target = now_s, self._shown, FREE
        self._fade_to(now_s)

    def _fade_to(self, now_s: float) -> None:
        gain = fade_gain(now_s - self._release_s, fade_s=self.settings.fade_s)
        self._shown = fade(self._released, gain=gain) if gain > 0 else FREE
        if gain == 0:
            self._release_s = None

    def _fit_watchdog(self) -> None:
        """Give the connected display a watchdog longer than ``keepalive_s`` if it has a shorter
        one (it would go free between two keep-alives while holding a value); DisplayError when
        the display cannot be so configured."""
        info = self.display.info
        keepalive_s = self.settings.keepalive_s
        if info is None or not info.watchdog_ms or keepalive_s * 1e3 < info.watchdog_ms:
            return
        wanted_ms = watchdog_for(keepalive_s)
        try:
            self.display.configure(watchdog_ms=wanted_ms)
        except DisplayError as exc:
            raise DisplayError(
                f"its watchdog_ms = {info.watchdog_ms} ms is not longer than [display] keepalive_s = "
                f"{keepalive_s:g} s and setting it to {wanted_ms} ms failed ({exc}); not using it"
            ) from exc
        log.warning("%s: watchdog_ms = %d ms was not longer than [display] keepalive_s = %g s (it would "
                    "go free while holding a value): set it to %d ms",
                    self.display, info.watchdog_ms, keepalive_s, wanted_ms)

    def _output(self, now_s: float) -> None:
        was_connected = self.display.connected
        if was_connected:  # connected by someone else: the Reconnector's accept did not see it
            try:
                self._fit_watchdog()
            except DisplayError as exc:
                self._reconnector.reject(now_s, exc)
        if self._reconnector.poll(now_s) and not was_connected:
            self.stats.connects += 1
            # reconnect() resent the display's last command: that is what it shows now.
            self._last_written, self._last_write_s = self.display.last_command, now_s
        info = self.display.info
        if info is None:
            return
        self._command = to_command(
            self._shown,
            level_max=info.level_max,
            stale=self._stale(now_s),
            fading=self._release_s is not None,
        )
        if not self.display.connected:
            return
        if (
            self._command == self._last_written
            and now_s - self._last_write_s < self.settings.keepalive_s
        ):
            return
        try:
            self.display.write_command(self._command)
        except DisplayError as exc:
            self.stats.write_failures += 1
            log.warning("%s: write failed (%s); reconnecting", self.display, exc)
            return
        self._last_written, self._last_write_s = self._command, now_s
        self.stats.reports_sent += 1
        if self._pending_t_s is not None:
            self.stats.last_latency_s = now_s - self._pending_t_s
            self._pending_t_s = None
