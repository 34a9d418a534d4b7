"""Which device backends are simulated: each backend class says it, asked through the name tables."""

from __future__ import annotations

import logging
import subprocess
import sys

import pytest
from support import second_sim

from teleop.devices import camera, gripper, loadcell
from teleop.devices.simulated import FAMILIES, is_simulated, robot_is_simulated
from teleop.errors import BackendNotFoundError
from teleop.scene import load_scene
from teleop.session import session_source

SHIPPED = {"gripper": {"sim": True, "franky": False},
           "camera": {"sim": True, "opencv": False},
           "load cell": {"sim": True, "serial": False, "tcp": False}}


def test_every_family_has_a_table():
    tables = {"gripper": gripper.BACKENDS, "camera": camera.BACKENDS, "load cell": loadcell.BACKENDS}
    assert set(FAMILIES) == set(tables) == set(SHIPPED)


@pytest.mark.parametrize(("family", "backend", "simulated"),
                         [(f, b, s) for f, backends in SHIPPED.items() for b, s in backends.items()])
def test_only_the_shipped_sim_backends_are_simulated(family, backend, simulated):
    assert is_simulated(family, backend) is simulated


def test_a_backend_whose_module_cannot_be_imported_counts_as_hardware(monkeypatch, tmp_path, caplog):
    monkeypatch.setitem(loadcell.BACKENDS, "vendor", "no_such_vendor_module:Cell")
    assert is_simulated("load cell", "vendor") is False
    # A vendor library that fails otherwise (a shared object missing: OSError) is hardware's problem too.
    (tmp_path / "broken_vendor_module.py").write_text("raise OSError('libvendor.so.1: cannot open shared object file')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(loadcell.BACKENDS, "broken", "broken_vendor_module:Cell")
    with caplog.at_level(logging.WARNING, logger="teleop.devices.simulated"):
        assert is_simulated("load cell", "broken") is False
    assert "load cell backend 'broken' does not import (OSError: libvendor.so.1" in caplog.text


def test_asking_whether_the_robot_is_simulated_loads_no_simulator():
    script = ("import sys; from teleop.session.recorder import session_source; from teleop.settings import "
              "load_settings; assert session_source(load_settings()) == 'simulated'; "
              "print(sorted(m for m in sys.modules if m.startswith(('teleop.sim', 'teleop.devices.live_sim'))))")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"


def test_an_unknown_backend_or_family_is_refused_naming_what_there_is():
    with pytest.raises(BackendNotFoundError, match="no gripper backend named 'nope'; available: franky, sim"):
        is_simulated("gripper", "nope")
    with pytest.raises(ValueError, match="no device family 'arm'; expected one of gripper, camera, load cell"):
        is_simulated("arm", "sim")


def test_a_second_simulated_gripper_leaves_the_robot_and_its_sessions_simulated(monkeypatch):
    second_sim.register(monkeypatch)
    settings = second_sim.with_gripper(load_scene("quick").settings)
    assert is_simulated("gripper", second_sim.NAME)
    assert robot_is_simulated(settings)
    assert session_source(settings) == "simulated"
    assert session_source(second_sim.with_gripper(settings, "franky")) == "hardware"
