"""Operator input devices: the base class and a name table of backends imported on use
(see :mod:`haptics.inputs.base`).

Typical use::

    with make_input(None, settings) as device:   # the settings' [operator] input
        reading = device.read(timeout_s=0.02)
"""

from haptics.inputs.base import (
    BACKENDS,
    OperatorInput,
    OperatorInputDevice,
    input_class,
    make_input,
)

__all__ = ["BACKENDS", "OperatorInput", "OperatorInputDevice", "input_class", "make_input"]
