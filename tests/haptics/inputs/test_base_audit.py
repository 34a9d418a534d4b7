"""Audit of the operator input base (:mod:`haptics.inputs.base`): a reading refuses a bool where a
number or a non-bool where a flag belongs, a second ``connect()`` keeps the state, ``feel`` checks the
stiffness, and a backend returning no reading is named."""

from __future__ import annotations

import pytest

from haptics.errors import OperatorInputError
from haptics.inputs.base import OperatorInput, OperatorInputDevice
from haptics.inputs.keyboard import KeyboardInput


@pytest.mark.parametrize("field", ["t_s", "grip"])
def test_a_bool_is_no_number_in_a_reading(field):
    values = {"t_s": 0.0, "grip": 0.0, field: True}
    with pytest.raises(OperatorInputError, match=f"OperatorInput.{field} = True: expected a finite number"):
        OperatorInput(enable=False, **values)


def test_a_reading_refuses_a_lost_flag_that_is_not_a_bool():
    with pytest.raises(OperatorInputError, match="OperatorInput.lost = 1: expected True or False"):
        OperatorInput(t_s=0.0, grip=0.0, enable=False, lost=1)


def test_a_bool_timeout_is_refused():
    with KeyboardInput() as device, pytest.raises(OperatorInputError, match="timeout_s = True"):
        device.read(timeout_s=True)


@pytest.mark.parametrize("stiffness", [float("nan"), float("inf"), "soft", True])
def test_feel_refuses_a_stiffness_that_is_no_finite_number(stiffness):
    with KeyboardInput() as device, pytest.raises(OperatorInputError, match="stiffness = "):
        device.feel(force_n=1.0, width_m=0.05, stiffness=stiffness)


def test_connect_on_a_connected_device_keeps_its_state():
    # A second connect() is a no-op: it must not open the device again (which resets the grip and
    # the enable, or drains a pad's pending presses).
    with KeyboardInput(grip_step=0.25) as device:
        device.press("up")
        device.press("e")
        device.press("g")
        assert device.connect() is device
        reading = device.read()
        assert (reading.grip, reading.enable, reading.buttons) == (0.25, True, {"grasp"})


class _Broken(OperatorInputDevice):
    """A backend whose ``_read`` returns something that is no OperatorInput."""

    name = "broken"

    @classmethod
    def from_settings(cls, settings, **options):
        return cls()

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    def _read(self, timeout_s: float):
        return {"grip": 0.5, "enable": True}


def test_a_backend_read_that_returns_no_reading_is_a_type_error_naming_it():
    with _Broken() as device, pytest.raises(TypeError, match=r"<_Broken>\._read returned .*expected an OperatorInput"):
        device.read()
