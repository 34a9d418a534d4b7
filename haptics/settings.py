"""The operator side's own settings: the ``[display]`` and ``[operator]`` tables of the settings file.

``[display]`` is built from a loaded :class:`~teleop.settings.Settings` by :func:`display_settings`,
which completes the rigid end: ``e_rigid_pa = 0`` (the default) stands for the sensor's resolution
limit (:attr:`teleop.settings.Settings.resolution_limit_pa`), beyond which the estimator reports
only a lower bound, so anything at or above it is rendered rigid.

``[operator]`` (:func:`operator_settings`) chooses the operator input device
(:mod:`haptics.inputs`) and configures its backends. Every key has a default, so the shipped file
leaves the table out; a deployment with a gamepad writes for instance::

    [operator]
    input = "gamepad"
    gamepad_path = "/dev/input/by-id/usb-Microsoft_Controller-event-joystick"  # "": the first pad with the trigger axis
    gamepad_trigger = "ABS_RZ"      # the analogue trigger that sets the grip (scaled by its min..max)
    gamepad_enable = "BTN_TR"       # the dead-man: enabled while held
    gamepad_grasp = "BTN_SOUTH"     # face buttons; "" leaves a button unmapped
    gamepad_release = "BTN_EAST"
    gamepad_stop = "BTN_WEST"
    gamepad_next = "BTN_NORTH"
    gamepad_quit = "BTN_SELECT"
    keyboard_grip_step = 0.05       # grip change per up/down key press, 0.001 .. 1
    sim_seed = 0                    # the simulated operator's seed
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

from teleop.errors import SettingsError
from teleop.physics import WEBER_FRACTION
from teleop.settings import Section, Settings
from teleop.settings_fields import spec

__all__ = ["INPUT_BACKENDS", "KEYBOARD_GRIP_STEP_MIN", "MIN_DISPLAY_STEPS", "DisplaySettings", "OperatorSettings",
           "display_range_pa", "display_settings", "display_warnings", "operator_settings"]

#: The fewest just-noticeable steps of E (:data:`~teleop.physics.WEBER_FRACTION` each) the display's
#: range must span: a narrower one renders next to everything at one end, soft or rigid.
MIN_DISPLAY_STEPS = 2

#: The smallest keyboard grip step: a thousandth of the grip range. A smaller step would take
#: thousands of key presses to move the grip at all noticeably (and rounds away entirely near 1e-9).
KEYBOARD_GRIP_STEP_MIN = 1e-3


_MIN_RANGE_RATIO = (1.0 + WEBER_FRACTION) ** MIN_DISPLAY_STEPS  # e_rigid_pa / e_soft_pa at least
_LIMIT_ROUNDING = 1e-3  # a rigid end written as the limit, rounded to 4 digits, is the limit


@dataclass(frozen=True)
class DisplaySettings(Section):
    """Operator-side softness display and the E-to-stiffness mapping."""

    TABLE = "display"

    backend: str = spec("sim", choices=("sim", "hid"))
    vendor_id: int = spec(0x1209, lo=0, hi=0xFFFF)
    product_id: int = spec(0x5EF7, lo=0, hi=0xFFFF)
    e_soft_pa: float = spec(5.0e3, lo=0.0, hi=1e12, lo_open=True, doc="E felt as the softest setting")
    e_rigid_pa: float = spec(0.0, lo=0.0, hi=1e13, doc="E at and above which it feels rigid; 0: the estimating "
                             "sensor's resolution limit (Settings.resolution_limit_pa)")
    smoothing_s: float = spec(0.1, lo=0.0, hi=10.0)
    fade_s: float = spec(0.3, lo=0.0, hi=10.0)
    stale_after_s: float = spec(1.0, lo=0.0, hi=60.0, lo_open=True)
    keepalive_s: float = spec(0.2, lo=0.0, hi=60.0, lo_open=True,
                              doc="resend an unchanged command at least this often (below the display's watchdog_ms)")

    def _check(self) -> None:
        if self.e_rigid_pa and self.e_rigid_pa < self.e_soft_pa * _MIN_RANGE_RATIO:
            raise SettingsError(
                f"DisplaySettings.e_rigid_pa = {self.e_rigid_pa}: expected a value at least "
                f"{self.e_soft_pa * _MIN_RANGE_RATIO:.6g} Pa, {MIN_DISPLAY_STEPS} just-noticeable steps "
                f"({WEBER_FRACTION:.0%} each) above e_soft_pa = {self.e_soft_pa}"
            )

    def resolved(self, settings: Settings) -> DisplaySettings:
        """The rigid end set: 0 becomes ``settings``' resolution limit."""
        if self.e_rigid_pa:
            return self
        limit = settings.resolution_limit_pa
        if limit < self.e_soft_pa * _MIN_RANGE_RATIO:
            raise SettingsError(f"DisplaySettings.e_soft_pa = {self.e_soft_pa}: expected a value at most "
                                f"{limit / _MIN_RANGE_RATIO:.4g} Pa, {MIN_DISPLAY_STEPS} just-noticeable steps "
                                f"({WEBER_FRACTION:.0%} each) below the sensor's resolution limit {limit:.4g} Pa "
                                "(the display's rigid end, e_rigid_pa = 0)")
        return dataclasses.replace(self, e_rigid_pa=limit)


def display_warnings(settings: Settings) -> list[str]:
    """What in ``settings``' display table is valid but defeats the display: a rigid end above the
    sensor's resolution limit, which no estimate reaches (estimates stop at the limit), so that no
    object is ever felt rigid. (Not refused: session logs recorded with one must still read.)"""
    rigid, limit = display_settings(settings).e_rigid_pa, settings.resolution_limit_pa
    if rigid <= limit * (1 + _LIMIT_ROUNDING):
        return []
    return [f"[display] e_rigid_pa = {rigid:.4g} Pa is above the sensor's resolution limit {limit:.4g} Pa: no "
            "estimate goes beyond the limit, so no object will feel rigid; set it at most that, or 0 for the limit"]


def display_settings(settings: Settings) -> DisplaySettings:
    """The ``[display]`` table of ``settings``, checked, with its rigid end resolved."""
    return settings.section(DisplaySettings)


def display_range_pa(settings: Settings) -> tuple[float, float]:
    """The display's ``(e_soft_pa, e_rigid_pa)`` under ``settings`` (Pa): what it renders, and the
    range felt errors are clipped to."""
    display = display_settings(settings)
    return display.e_soft_pa, display.e_rigid_pa


#: The operator input backends (:data:`haptics.inputs.base.BACKENDS` names the same).
INPUT_BACKENDS = ("keyboard", "gamepad", "display", "sim")
# The discrete buttons a gamepad maps, each to the field ``gamepad_<button>``.
_GAMEPAD_BUTTONS = ("grasp", "release", "stop", "next", "quit")


@dataclass(frozen=True)
class OperatorSettings(Section):
    """The operator input device (:mod:`haptics.inputs`) and its backends' keys and codes.

    Gamepad codes are Linux evdev names (``evdev.ecodes``): the trigger an ``ABS_*`` axis, the
    buttons ``BTN_*`` (or ``KEY_*``) keys. Which physical button carries which name depends on the
    pad and its kernel driver: ``evtest`` shows them.
    """

    TABLE = "operator"

    input: str = spec("keyboard", choices=INPUT_BACKENDS, doc="operator input device")
    gamepad_path: str = spec("", doc="evdev device path; '': the first device with the trigger axis")
    gamepad_trigger: str = spec("ABS_RZ", doc="absolute axis setting the grip, scaled by its min..max to 0..1")
    gamepad_enable: str = spec("BTN_TR", doc="dead-man button: enabled while held")
    gamepad_grasp: str = spec("BTN_SOUTH", doc="button: grasp at the chosen force; '': unmapped")
    gamepad_release: str = spec("BTN_EAST", doc="button: release; '': unmapped")
    gamepad_stop: str = spec("BTN_WEST", doc="button: stop the fingers; '': unmapped")
    gamepad_next: str = spec("BTN_NORTH", doc="button: next object; '': unmapped")
    gamepad_quit: str = spec("BTN_SELECT", doc="button: quit; '': unmapped")
    keyboard_grip_step: float = spec(0.05, lo=KEYBOARD_GRIP_STEP_MIN, hi=1.0,
                                     doc="grip change per up/down key, a fraction of the grip range")
    sim_seed: int = spec(0, lo=0, hi=2**63 - 1, doc="seed of the simulated operator")

    def _check(self) -> None:
        if not self.gamepad_trigger.startswith("ABS_"):
            raise SettingsError(f"OperatorSettings.gamepad_trigger = {self.gamepad_trigger!r}: expected an "
                                "absolute axis name such as 'ABS_RZ'")
        if not self.gamepad_enable:
            raise SettingsError("OperatorSettings.gamepad_enable = '': expected a button name such as 'BTN_TR' "
                                "(the dead-man cannot be left unmapped)")
        seen: dict[str, str] = {}
        for key, code in self.gamepad_buttons().items():
            if not code.startswith(("BTN_", "KEY_")):
                raise SettingsError(f"OperatorSettings.gamepad_{key} = {code!r}: expected a button name such "
                                    "as 'BTN_SOUTH' (or '' to leave it unmapped)")
            if code in seen:
                raise SettingsError(f"OperatorSettings.gamepad_{key} = {code!r}: already gamepad_{seen[code]}")
            seen[code] = key
        known = _evdev_codes()
        if known is None:
            return  # without evdev the gamepad cannot open: nothing to check the names against
        for key, code in {"trigger": self.gamepad_trigger, **self.gamepad_buttons()}.items():
            if code not in known:
                raise SettingsError(f"OperatorSettings.gamepad_{key} = {code!r}: evdev knows no such code (see "
                                    "evdev.ecodes, or run evtest to see what the pad sends)")
        # Two names of one code (BTN_Y and BTN_WEST are both 308) would be one physical button.
        # The trigger is an EV_ABS axis, the buttons EV_KEY keys: only the buttons share a code space.
        by_code: dict[int, tuple[str, str]] = {}
        for key, name in self.gamepad_buttons().items():
            code = known[name]
            if code in by_code:
                other_key, other_name = by_code[code]
                raise SettingsError(f"OperatorSettings.gamepad_{key} = {name!r}: the same evdev code {code} as "
                                    f"gamepad_{other_key} = {other_name!r} (two names of one button); "
                                    "map each to its own button")
            by_code[code] = (key, name)

    def gamepad_buttons(self) -> dict[str, str]:
        """Button name -> evdev key name for ``"enable"`` and every mapped discrete button."""
        named = {"enable": self.gamepad_enable}
        named.update({b: getattr(self, f"gamepad_{b}") for b in _GAMEPAD_BUTTONS})
        return {b: code for b, code in named.items() if code}


def _evdev_codes() -> Mapping[str, int] | None:
    """evdev's table of code names (a pure table: importing it opens no device); None without evdev."""
    try:
        from evdev import ecodes
    except ImportError:
        return None
    return ecodes.ecodes


def operator_settings(settings: Settings) -> OperatorSettings:
    """The ``[operator]`` table of ``settings``, checked (defaults where the file has none)."""
    return settings.section(OperatorSettings)
