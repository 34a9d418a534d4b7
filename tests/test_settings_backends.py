"""Each backend setting allows exactly the backends its family's name table holds.

The settings cannot derive their ``choices`` from the tables (the shared base does not import the
devices), so this is where a backend added to one side only is caught.
"""

from __future__ import annotations

import dataclasses
import importlib

import pytest

from haptics.settings import DisplaySettings, OperatorSettings
from teleop.settings import GripperSettings, LoadCellSettings, SensorSettings

# family -> (the settings class, its backend field, the module holding the family's BACKENDS table)
FAMILIES = {
    "camera": (SensorSettings, "camera_backend", "teleop.devices.camera"),
    "gripper": (GripperSettings, "backend", "teleop.devices.gripper"),
    "load cell": (LoadCellSettings, "backend", "teleop.devices.loadcell"),
    "display": (DisplaySettings, "backend", "haptics.devices"),
    "operator input": (OperatorSettings, "input", "haptics.inputs.base"),
}


def test_every_teleop_device_family_is_checked_here():
    from teleop.devices.simulated import FAMILIES as DEVICE_FAMILIES

    assert {name: module for name, (_, _, module) in FAMILIES.items() if name in DEVICE_FAMILIES} == DEVICE_FAMILIES


@pytest.mark.parametrize("family", FAMILIES)
def test_the_setting_allows_exactly_the_backends_in_the_table(family):
    settings, name, module = FAMILIES[family]
    choices = {f.name: f.metadata["choices"] for f in dataclasses.fields(settings)}[name]
    table = importlib.import_module(module).BACKENDS
    where = f"{settings.__name__}.{name}"
    unsettable, unknown = sorted(set(table) - set(choices)), sorted(set(choices) - set(table))
    assert not unsettable, f"{module}.BACKENDS has backend(s) {unsettable} that {where} does not allow"
    assert not unknown, f"{where} allows backend(s) {unknown} that are not in {module}.BACKENDS"
