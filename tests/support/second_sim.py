"""A second simulated backend of a device family, registered for one test as a new backend would be:
a subclass of the shipped simulated class under another name in the family's table."""

from __future__ import annotations

import copy
import dataclasses
import sys
import types

import pytest

from teleop.devices import camera, gripper, loadcell
from teleop.devices.playback import SimulatedCamera, SimulatedGripper, SimulatedLoadCell
from teleop.settings import Settings

NAME = "sim_slow"
MODULE = "support_second_sim_backend"  # the module the table entries name, made for the test
SHIPPED = {"gripper": (gripper.BACKENDS, SimulatedGripper), "camera": (camera.BACKENDS, SimulatedCamera),
           "load cell": (loadcell.BACKENDS, SimulatedLoadCell)}


def register(monkeypatch: pytest.MonkeyPatch, family: str = "gripper") -> type:
    """Put a subclass of ``family``'s shipped simulated class in its table as :data:`NAME` until the test ends."""
    table, base = SHIPPED[family]
    cls = type(f"Slow{base.__name__}", (base,), {"__doc__": f"A second simulated {family} backend."})
    module = sys.modules.get(MODULE) or types.ModuleType(MODULE)
    setattr(module, cls.__name__, cls)
    monkeypatch.setitem(sys.modules, MODULE, module)
    monkeypatch.setitem(table, NAME, f"{MODULE}:{cls.__name__}")
    return cls


def _with(section, name: str):
    """``section`` with ``backend`` ``name``, set past the settings' own list of choices, which names
    only the shipped backends (``dataclasses.replace`` would check them again)."""
    section = copy.copy(section)
    object.__setattr__(section, "backend", name)
    return section


def with_gripper(settings: Settings, name: str = NAME) -> Settings:
    """``settings`` with gripper backend ``name``."""
    return dataclasses.replace(settings, gripper=_with(settings.gripper, name))


def with_load_cell(settings: Settings, name: str = NAME) -> Settings:
    """``settings`` with load cell backend ``name``."""
    return dataclasses.replace(settings, load_cell=_with(settings.load_cell, name))
