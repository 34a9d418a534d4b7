"""Fixtures of the operator input tests: fakes of the devices and one rig per input backend.

No input device exists here, so the gamepad is tested through :class:`FakeEvdevDevice` (the
interface of ``evdev.InputDevice`` that the backend uses, with the kernel's real codes and event
type), the display's grip through :class:`FakeGripDisplay` (a ``SoftnessDisplay``'s
``connect``/``info``/``read_operator_reports``/``close``) and the simulated operator's sequencing
through :class:`ScriptedOperator` (the real one is tested closed loop in ``test_sim_input.py``).
"""

from __future__ import annotations

import errno
import itertools
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from types import SimpleNamespace

import pytest
from evdev import AbsInfo, InputEvent, ecodes

from haptics.errors import DisplayError, DisplayNotConnectedError
from haptics.inputs.base import OperatorInputDevice
from haptics.protocol_grip import GripReport
from teleop.sim.operator import OperatorCommand

PAD_KEYS = ("BTN_TR", "BTN_SOUTH", "BTN_EAST", "BTN_WEST", "BTN_NORTH", "BTN_SELECT")


class FakeEvdevDevice:
    """Stands in for ``evdev.InputDevice``: capabilities, absinfo, active_keys, read_one, read, close;
    unplugged, every call raises OSError(ENODEV) as the kernel's does."""

    def __init__(self, path: str = "/dev/input/event7", name: str = "Fake Pad", *,
                 axes: dict[str, tuple[int, int]] | None = None, keys: tuple[str, ...] = PAD_KEYS) -> None:
        self.path, self.name = path, name
        axes = {"ABS_X": (-32768, 32767), "ABS_Z": (0, 255), "ABS_RZ": (0, 255)} if axes is None else axes
        self.axes = {ecodes.ecodes[a]: AbsInfo(value=lo, min=lo, max=hi, fuzz=0, flat=0, resolution=0)
                     for a, (lo, hi) in axes.items()}
        self.keys = {ecodes.ecodes[k] for k in keys}
        self.held: set[int] = set()
        self.queue: deque[InputEvent] = deque()
        self.unplugged = False
        self.closed = False
        self._clock = itertools.count()

    # --------------------------------------------------------------- evdev.InputDevice's interface

    def _live(self) -> None:
        if self.unplugged:
            raise OSError(errno.ENODEV, "No such device")

    def capabilities(self, verbose: bool = False, absinfo: bool = True) -> dict[int, list]:
        self._live()
        caps = {ecodes.EV_SYN: [ecodes.SYN_REPORT]}
        if self.keys:
            caps[ecodes.EV_KEY] = sorted(self.keys)
        if self.axes:
            caps[ecodes.EV_ABS] = [(code, info) if absinfo else code for code, info in sorted(self.axes.items())]
        return caps

    def absinfo(self, axis_num: int) -> AbsInfo:
        self._live()
        return self.axes[axis_num]

    def active_keys(self, verbose: bool = False) -> list[int]:
        self._live()
        return sorted(self.held)

    def read_one(self) -> InputEvent | None:
        self._live()
        return self.queue.popleft() if self.queue else None

    def read(self):
        self._live()
        if not self.queue:
            raise BlockingIOError(errno.EAGAIN, "Resource temporarily unavailable")
        while self.queue:
            yield self.queue.popleft()

    def close(self) -> None:
        self.closed = True

    # --------------------------------------------------------------- the hand on the pad

    def _event(self, type_: int, code: int, value: int) -> None:
        self.queue.append(InputEvent(0, next(self._clock), type_, code, value))

    def syn(self) -> None:
        self._event(ecodes.EV_SYN, ecodes.SYN_REPORT, 0)

    def move(self, axis: str, value: int, *, report: bool = True) -> None:
        code = ecodes.ecodes[axis]
        self.axes[code] = self.axes[code]._replace(value=value)
        if report:
            self._event(ecodes.EV_ABS, code, value)
            self.syn()

    def key(self, name: str, value: int, *, report: bool = True) -> None:
        """1 press, 2 key repeat, 0 release."""
        code = ecodes.ecodes[name]
        if value:
            self.held.add(code)
        else:
            self.held.discard(code)
        if report:
            self._event(ecodes.EV_KEY, code, value)
            self.syn()

    def tap(self, name: str) -> None:
        self.key(name, 1)
        self.key(name, 0)

    def drop(self) -> None:
        """The kernel's buffer overflowed: events lost, SYN_DROPPED queued."""
        self._event(ecodes.EV_SYN, ecodes.SYN_DROPPED, 0)


class FakeGripDisplay:
    """A softness display's operator side: ``connect``, ``info.protocol_version``,
    ``read_operator_reports`` (which waits up to its timeout for a report, as the real one does)."""

    def __init__(self, protocol_version: int = 2) -> None:
        self.protocol_version = protocol_version
        self.connected = False
        self.info = None
        self.reports: deque[GripReport] = deque()
        self.unplugged = False
        self.connects = self.closes = 0
        self._sequence = 0
        self._pushed = threading.Condition()

    def connect(self):
        if self.unplugged:
            raise DisplayError("fake display: no such device")
        self.connected = True
        self.connects += 1
        self.info = SimpleNamespace(protocol_version=self.protocol_version)
        return self.info

    def close(self) -> None:
        self.connected = False
        self.closes += 1

    def read_operator_reports(self, *, timeout_s: float) -> tuple[GripReport, ...]:
        if not self.connected:
            raise DisplayNotConnectedError("fake display: not connected")
        if self.unplugged:
            self.connected = False
            raise DisplayError("fake display: device disconnected")
        if self.protocol_version < 2:
            return ()
        with self._pushed:
            self._pushed.wait_for(lambda: self.reports, timeout=timeout_s)
            # Every report since the last call at once, as SoftnessDisplay returns them.
            reports, self.reports = tuple(self.reports), deque()
        return reports

    def push(self, grip: float, *, force_n: float | None = None, enable: bool = True,
             buttons: tuple[str, ...] = ()) -> None:
        with self._pushed:
            self.reports.append(GripReport(grip, force_n, enable, frozenset(buttons), self._sequence))
            self._pushed.notify_all()
        self._sequence = (self._sequence + 1) % 256


@dataclass
class Controls:
    """What the scripted operators command next; shared by every operator the backend draws."""

    target_width_m: float = 0.08
    enable: bool = False
    release: bool = False  # True: the next step releases (once)
    finish: bool = False  # True: the next step finds the fingers open again (done)


class ScriptedOperator:
    """Stands in for ``teleop.sim.operator.SimulatedOperator``: does what :class:`Controls` say."""

    def __init__(self, controls: Controls, rng, *, max_width_m: float, max_force_n: float) -> None:
        self.controls, self.rng = controls, rng
        self.max_width_m, self.max_force_n = max_width_m, max_force_n
        self.steps: list[tuple[float, float, float]] = []
        self.done = False

    def step(self, t_s: float, *, force_n: float, width_m: float) -> OperatorCommand:
        self.steps.append((t_s, force_n, width_m))
        c = self.controls
        release, c.release = c.release, False
        if c.finish:
            self.done, c.finish = True, False
        return OperatorCommand(target_width_m=c.target_width_m, enable=c.enable, release=release)


@dataclass
class InputRig:
    """An input device under test and the hand that works it."""

    device: OperatorInputDevice
    set_grip: Callable[[float], None]
    set_enable: Callable[[bool], None]
    press: Callable[[str], None]  # one press of a button, reported by the next read
    buttons: tuple[str, ...]  # the buttons this rig can press
    fake: object = None
    extra: dict = field(default_factory=dict)


def keyboard_rig() -> InputRig:
    from haptics.inputs.keyboard import KeyboardInput

    device = KeyboardInput(grip_step=0.05)
    state = {"enable": False}

    def set_grip(grip: float) -> None:
        device.press("o")
        for _ in range(round(grip / device.grip_step)):
            device.press("up")

    def set_enable(on: bool) -> None:
        if not device.connected:  # nothing to press; connect() starts not enabled
            state["enable"] = False
        elif on != state["enable"]:
            device.press("e")
            state["enable"] = on

    def press(button: str) -> None:
        device.press({"grasp": "g", "release": "r", "stop": "s", "next": "n", "quit": "q"}[button])
        if button in ("release", "stop"):
            state["enable"] = False

    return InputRig(device, set_grip, set_enable, press, ("grasp", "release", "stop", "next", "quit"))


def gamepad_rig() -> InputRig:
    from haptics.inputs.gamepad import GamepadInput

    pad = FakeEvdevDevice()
    device = GamepadInput(device=pad)
    codes = {"grasp": "BTN_SOUTH", "release": "BTN_EAST", "stop": "BTN_WEST", "next": "BTN_NORTH",
             "quit": "BTN_SELECT"}
    return InputRig(
        device,
        set_grip=lambda grip: pad.move("ABS_RZ", round(grip * 255)),
        set_enable=lambda on: pad.key("BTN_TR", int(on)),
        press=lambda button: pad.tap(codes[button]),
        buttons=tuple(codes),
        fake=pad,
    )


def display_rig() -> InputRig:
    from haptics.inputs.display import DisplayInput

    display = FakeGripDisplay()
    device = DisplayInput(display)
    state = {"grip": 0.0, "enable": False}

    def set_grip(grip: float) -> None:
        state["grip"] = grip
        display.push(grip, enable=state["enable"])

    def set_enable(on: bool) -> None:
        state["enable"] = on
        display.push(state["grip"], enable=on)

    def press(button: str) -> None:
        display.push(state["grip"], enable=state["enable"], buttons=(button,))
        display.push(state["grip"], enable=state["enable"])

    return InputRig(device, set_grip, set_enable, press, ("grasp", "release", "stop", "next"), fake=display)


def sim_rig() -> InputRig:
    from haptics.inputs.sim import SimulatedInput

    controls = Controls()
    operators: list[ScriptedOperator] = []

    def factory(rng, **kwargs) -> ScriptedOperator:
        operators.append(ScriptedOperator(controls, rng, **kwargs))
        return operators[-1]

    # The contract's hand is at the device already: its first read is the script's (test_sim_input.py
    # tests the default, an idle first read).
    device = SimulatedInput(seed=3, max_width_m=0.08, max_force_n=30.0, operator_factory=factory,
                            starts_released=False)

    def set_grip(grip: float) -> None:
        controls.target_width_m = 0.08 * (1 - grip)

    def set_enable(on: bool) -> None:
        controls.enable = on

    def press(button: str) -> None:
        if button == "release":
            controls.release = True
        else:
            controls.finish = True

    return InputRig(device, set_grip, set_enable, press, ("release", "next"), fake=controls,
                    extra={"operators": operators})


RIGS = {"keyboard": keyboard_rig, "gamepad": gamepad_rig, "display": display_rig, "sim": sim_rig}


@pytest.fixture
def input_rig_backends() -> set[str]:
    """The operator input backends the ``input_rig`` fixture runs the contract suite on."""
    return set(RIGS)


@pytest.fixture(params=sorted(RIGS))
def input_rig(request: pytest.FixtureRequest) -> InputRig:
    """Every operator input backend in turn; closed after the test."""
    made = RIGS[request.param]()
    yield made
    made.device.close()



@pytest.fixture
def with_operator(settings):
    """``with_operator(**keys)``: the shipped settings with an ``[operator]`` table of ``keys``."""

    def make(**keys):
        from haptics.settings import OperatorSettings

        return settings.with_section(OperatorSettings(**keys))

    return make


@pytest.fixture
def make_pad() -> type[FakeEvdevDevice]:
    """The fake evdev device class: ``make_pad(path, name, axes=..., keys=...)``."""
    return FakeEvdevDevice


@pytest.fixture
def make_grip_display() -> type[FakeGripDisplay]:
    """The fake display class: ``make_grip_display(protocol_version=2)``."""
    return FakeGripDisplay
