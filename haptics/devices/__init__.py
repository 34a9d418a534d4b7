"""Softness displays: the base class and a name table of backends imported on use.

Typical use::

    with make_display(display_settings(settings)) as display:
        display.write_command(StiffnessCommand(level=100))
"""

from __future__ import annotations

from typing import Any

from haptics.devices.base import Reconnector, SoftnessDisplay
from haptics.errors import DisplayBackendNotFoundError
from haptics.settings import DisplaySettings
from teleop.devices.base import load_backend
from teleop.errors import BackendNotFoundError

__all__ = ["BACKENDS", "Reconnector", "SoftnessDisplay", "display_class", "make_display"]

#: Backend name -> "module:class"; the module is imported only when the backend is used.
BACKENDS = {
    "sim": "haptics.devices.sim:SimulatedDisplay",
    "hid": "haptics.devices.hid:HidDisplay",
}


def display_class(name: str) -> type[SoftnessDisplay]:
    """The display class registered as ``name``; the error lists the names there are."""
    try:
        return load_backend("display", BACKENDS, name)
    except BackendNotFoundError as exc:
        raise DisplayBackendNotFoundError(str(exc)) from exc


def make_display(settings: DisplaySettings, **options: Any) -> SoftnessDisplay:
    """The display ``settings.backend`` names, configured from ``settings``, not yet connected."""
    return display_class(settings.backend).from_settings(settings, **options)
