"""``teleop calibrate gripper`` end to end: the franky backend against franky-sim, a load cell on TCP.

What is simulated: franky-sim (MuJoCo) moves the Franka hand's fingers, position-controlled,
with nothing between them; it has no finger compliance to configure. The rigid reference
object and the fingers' compliance live in the load cell instead: an HX711 bridge
(:class:`~teleop.devices.hx711_bridge.Hx711Bridge`, served on loopback to the ``tcp``
backend) whose fake cell reads, at 80 Hz with noise,

    F = K_TRUE * max(0, W - width)

where ``width`` is the simulated hand's width at that instant: the force a finger of stiffness
K_TRUE feels when the motor closes past contact with a rigid object of width W. The settings
configure a different stiffness (the prior the command starts from); the command must find
K_TRUE from the forces and widths it reads. franky-sim's fingers stop about 0.5 mm short of a
commanded width (the offset of its finger controller), where a real hand's force control would
press on; so the simulated fingers are soft (10 kN/m: millimetres of squeeze) and the prior
softer still, so that every squeeze gets past contact.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil

import numpy as np
import pytest

from teleop.cli import main
from teleop.devices.hx711_bridge import FakeHx711, Hx711Bridge
from teleop.rig import gripper_calibration
from teleop.rig.gripper_calibration import Squeeze, fit_finger_stiffness, squeeze_reference
from teleop.settings import default_settings_path, load_settings
from teleop.settings_edit import update_settings_file

K_TRUE = 1.0e4  # N/m
K_CONFIGURED = 8.0e3
WIDTH_M = 0.05
COUNTS_PER_N = 42000.0
TARE = 1234


@pytest.mark.slow
def test_recovers_the_finger_stiffness_through_franky_sim(franky_sim_robot, tmp_path, capsys):
    cell = FakeHx711(counts_per_n=COUNTS_PER_N, tare_counts=TARE, rate_hz=80.0, noise_counts=0.02 * COUNTS_PER_N,
                     force_n=lambda _t: K_TRUE * max(0.0, WIDTH_M - franky_sim_robot.hand_width))
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    with Hx711Bridge(cell, host="127.0.0.1", port=0) as bridge:
        update_settings_file(path, {
            "gripper.backend": "franky", "gripper.host": franky_sim_robot.hostname,
            "gripper.closing_speed_m_s": 0.05, "gripper.width_read_hz": 20.0,
            "gripper.finger_stiffness_n_per_m": K_CONFIGURED,
            "load_cell.backend": "tcp", "load_cell.address": bridge.address,
            "load_cell.counts_per_n": COUNTS_PER_N, "load_cell.tare_counts": TARE,
        })
        code = main(["calibrate", "gripper", "--settings", str(path), "--object-width-mm", str(WIDTH_M * 1e3),
                     "--repeats", "2", "--levels", "4", "--settle-s", "0.2", "--average-s", "0.3", "--json"])
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert code == 0, result
    assert result["stiffness_n_per_m"] == pytest.approx(K_TRUE, rel=0.10)
    assert 0 < result["stiffness_se_n_per_m"] < 0.05 * result["stiffness_n_per_m"]
    assert result["contact_width_m"] == pytest.approx(WIDTH_M, abs=5e-4)
    assert len(result["squeezes"]) == 8 and len(result["per_repeat_n_per_m"]) == 2
    forces = [s["force_n"] for s in result["squeezes"]]
    assert min(forces) > 1.0 and max(forces) > 3 * min(forces)  # the cell read real squeezes at four levels
    assert load_settings(path).gripper.finger_stiffness_n_per_m == pytest.approx(result["stiffness_n_per_m"],
                                                                                   rel=1e-3)


def _squeezes(stiffness: float, *, scatter_m: float = 0.0, width_m: float = WIDTH_M) -> list[Squeeze]:
    rng = np.random.default_rng(0)
    out = []
    for repeat in range(3):
        for force in (5.0, 10.0, 20.0, 30.0):
            out.append(Squeeze(repeat, force, force, 0.01, width_m - force / stiffness + rng.normal(0.0, scatter_m)))
    return out


def test_fit_recovers_an_exact_line_per_repeat_too():
    fit = fit_finger_stiffness(_squeezes(1.2e5, scatter_m=1e-7), object_width_m=WIDTH_M)
    assert fit and fit.stiffness_n_per_m == pytest.approx(1.2e5, rel=0.01)
    assert all(k == pytest.approx(1.2e5, rel=0.02) for k in fit.per_repeat_n_per_m)
    assert fit.contact_width_m == pytest.approx(WIDTH_M, abs=1e-6)


@pytest.mark.parametrize("squeezes, object_width_m, start", [
    (_squeezes(1.2e5, scatter_m=5e-5), WIDTH_M, "too uncertain"),
    (_squeezes(-1.2e5), WIDTH_M, "the width does not fall"),
    (_squeezes(1.2e5), 0.03, "the fingers touch at 50.0 mm"),
    (_squeezes(1.2e5)[:2], WIDTH_M, "2 squeezes reached the object"),
    (_squeezes(math.inf), WIDTH_M, "the width does not fall"),  # divided by a zero slope
    (_squeezes(1.2e5)[:8] + _squeezes(math.inf)[8:], WIDTH_M, "the width does not fall"),  # the third repeat stalled
    (_squeezes(1.2e5, scatter_m=1e-7)[:8] + _squeezes(-1.2e5)[8:], WIDTH_M, "the width does not fall"),
    (_squeezes(900.0), WIDTH_M, "k = 900 N/m is outside what the settings take (1000 to 1e+09 N/m"),
    (_squeezes(2e9), WIDTH_M, "k = 2e+09 N/m is outside what the settings take"),
])
def test_refusals_say_why(squeezes, object_width_m, start):
    fit = fit_finger_stiffness(squeezes, object_width_m=object_width_m)
    assert not fit and fit.reason.startswith(start), fit.reason


def test_widths_that_never_change_in_any_repeat_are_refused_for_the_whole_line():
    fit = fit_finger_stiffness(_squeezes(math.inf), object_width_m=WIDTH_M)
    assert not fit and fit.reason.startswith("the width does not fall as the force rises (slope +0 um/N): is the "
                                             "reference between the fingers"), fit.reason


def test_a_stalled_repeat_is_named_and_its_stiffness_reported_infinite():
    fit = fit_finger_stiffness(_squeezes(1.2e5)[:8] + _squeezes(math.inf)[8:], object_width_m=WIDTH_M)
    assert not fit and "+0 um/N in repeat 3" in fit.reason, fit.reason
    assert fit.per_repeat_n_per_m == (pytest.approx(1.2e5), pytest.approx(1.2e5), math.inf)


def test_squeezes_that_never_reached_the_object_are_left_out():
    missed = [Squeeze(r, 2.0, 0.1, 0.01, WIDTH_M + 0.004) for r in range(3)]  # 0.1 N: the fingers closed on air
    fit = fit_finger_stiffness(_squeezes(1.2e5) + missed, object_width_m=WIDTH_M)
    assert fit and fit.n == 12 and fit.stiffness_n_per_m == pytest.approx(1.2e5, rel=1e-6)


def test_forces_spanning_too_little_are_refused():
    close = [Squeeze(r, f, f, 0.01, WIDTH_M - f / 1.2e5) for r in range(3) for f in (5.0, 5.5, 6.0)]
    fit = fit_finger_stiffness(close, object_width_m=WIDTH_M)
    assert not fit and fit.reason.startswith("9 squeezes reached the object") and "spanning 1 N" in fit.reason


def test_the_standard_error_is_the_slopes_propagated_to_the_stiffness():
    squeezes = _squeezes(1.2e5, scatter_m=2e-7)
    fit = fit_finger_stiffness(squeezes, object_width_m=WIDTH_M)
    force = np.array([s.force_n for s in squeezes])
    width = np.array([s.width_m for s in squeezes])
    (slope, _), cov = np.polyfit(force, width, 1, cov=True)  # residual variance over n - 2
    assert fit and fit.stiffness_se_n_per_m == pytest.approx(np.sqrt(cov[0, 0]) / slope**2, rel=1e-6)


class _Readings:
    def __init__(self, value):
        self.value = np.asarray(value)

    def __len__(self):
        return self.value.size


class RecordingGripper:
    """A hand at the reference's width that records each grasp as (width commanded, force)."""

    max_width_m = 0.08

    def __init__(self):
        self.grasps = []

    def move(self, width_m, *, speed_m_s=None):
        return True

    def grasp(self, width_m, *, speed_m_s=None, force_n=None, epsilon_inner_m=None, epsilon_outer_m=None):
        self.grasps.append((width_m, force_n))
        return True

    def widths(self, *, timeout_s=0.0):
        return _Readings([WIDTH_M])


class SteadyCell:
    def read(self, timeout_s=None):
        return _Readings([3.0, 3.0])


def test_each_squeeze_is_commanded_past_contact_by_the_configured_stiffness():
    gripper = RecordingGripper()
    squeeze_reference(gripper, SteadyCell(), object_width_m=WIDTH_M, forces_n=[10.0, 40.0], repeats=1,
                      configured_stiffness_n_per_m=2.0e3, speed_m_s=0.05, settle_s=0.0, average_s=0.0)
    assert gripper.grasps == [(pytest.approx(WIDTH_M - 10.0 / 2.0e3), 10.0), (pytest.approx(WIDTH_M - 40.0 / 2.0e3), 40.0)]


@pytest.fixture
def rig_file(tmp_path, monkeypatch):
    """(settings file with a tcp load cell, the grippers made): a refusal must come before the first."""
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, {"load_cell.backend": "tcp"})
    made = []

    def make_gripper(settings):
        made.append(settings)
        raise AssertionError("a gripper was made")

    monkeypatch.setattr(gripper_calibration, "make_gripper", make_gripper)
    return path, made


@pytest.mark.parametrize("option, value, expected", [
    ("--settle-s", "-1", "expected a number >= 0"),  # time.sleep's traceback with the reference in the fingers
    ("--settle-s", "nan", "expected a number >= 0"),
    ("--average-s", "-1", "expected a number > 0"),  # accepted
    ("--average-s", "nan", "expected a number > 0"),
    ("--max-se-percent", "nan", "expected a number > 0"),  # switched the check off
    ("--max-se-percent", "-1", "expected a number > 0"),
])
def test_bad_numbers_are_refused_before_the_gripper_moves(option, value, expected, rig_file, capsys):
    path, made = rig_file
    with pytest.raises(SystemExit) as exited:
        main(["calibrate", "gripper", "--settings", str(path), "--object-width-mm", "50", option, value])
    assert exited.value.code == 2 and not made
    assert f"argument {option}: '{value}': {expected}" in capsys.readouterr().err


@pytest.mark.parametrize("option, value, expected", [
    ("--max-force-n", "200", "--max-force-n 200: expected a force in (0, 140] N"),
    ("--levels", "1", "--repeats 3 --levels 1: expected >= 1 and >= 2"),
])
def test_out_of_range_counts_and_forces_are_refused_before_the_gripper_moves(option, value, expected, rig_file,
                                                                             capsys):
    path, made = rig_file
    assert main(["calibrate", "gripper", "--settings", str(path), "--object-width-mm", "50", option, value]) == 2
    assert expected in capsys.readouterr().err and not made


def test_forces_run_from_a_quarter_of_the_largest_up_to_it(rig_file):
    path, _ = rig_file
    args = argparse.Namespace(object_width_mm=50.0, repeats=1, levels=4, max_force_n=40.0)
    width_m, forces = gripper_calibration._check(args, load_settings(path))
    assert width_m == pytest.approx(0.05) and forces == pytest.approx([10.0, 20.0, 30.0, 40.0])


def test_a_read_only_settings_file_is_refused_before_the_gripper_moves(rig_file, capsys):
    path, made = rig_file
    path.chmod(0o444)
    assert main(["calibrate", "gripper", "--settings", str(path), "--object-width-mm", "50"]) == 2
    assert f"error: settings file {path} is read-only (mode 444)" in capsys.readouterr().err and not made
