"""Audit of :mod:`teleop.rig.gripper_calibration`: the fit's figures, its refusals at their limits, and
the squeezes' commands, with fake devices."""

from __future__ import annotations

import argparse
import math
import shutil

import numpy as np
import pytest

from teleop.rig import gripper_calibration
from teleop.rig.gripper_calibration import Squeeze, fit_finger_stiffness, squeeze_reference
from teleop.settings import default_settings_path, load_settings
from teleop.settings_edit import update_settings_file

WIDTH_M = 0.05
K = 1.0e5


def _squeezes(*, repeats=3, forces=(5.0, 10.0, 20.0, 30.0), k=K, width_m=WIDTH_M, miss_m=0.0):
    """Squeezes on the line ``width = width_m - F / k``, alternately ``miss_m`` above and below it."""
    out = []
    for repeat in range(repeats):
        for i, force in enumerate(forces):
            out.append(Squeeze(repeat, force, force, 0.01, width_m - force / k + (miss_m if i % 2 else -miss_m)))
    return out


def test_the_residual_is_the_root_mean_square_miss_of_the_line():
    # Each repeat's misses alternate -d, +d, -d, +d about the line: the least-squares line moves a
    # little towards them, so its rms miss is a little under d.
    fit = fit_finger_stiffness(_squeezes(miss_m=1e-6), object_width_m=WIDTH_M, max_relative_se=1.0)
    assert fit, fit.reason
    assert 0.85e-6 < fit.residual_m <= 1e-6


def test_repeats_of_two_squeezes_each_report_their_own_stiffness():
    fit = fit_finger_stiffness(_squeezes(forces=(5.0, 30.0)), object_width_m=WIDTH_M)
    assert fit, fit.reason
    assert fit.per_repeat_n_per_m == (pytest.approx(K), pytest.approx(K), pytest.approx(K))


def test_a_repeat_whose_width_rises_is_named_even_when_the_pooled_line_falls():
    squeezes = _squeezes(repeats=2) + [Squeeze(2, f, f, 0.01, WIDTH_M - 1e-4 + f * 1e-9) for f in (5.0, 30.0)]
    fit = fit_finger_stiffness(squeezes, object_width_m=WIDTH_M)
    assert not fit and "in repeat 3" in fit.reason and "in repeat 1" not in fit.reason


@pytest.mark.parametrize("contact_m, accepted", [(WIDTH_M + 0.004, True), (WIDTH_M - 0.004, True),
                                                 (WIDTH_M + 0.006, False), (WIDTH_M - 0.006, False)])
def test_a_contact_width_more_than_5_mm_either_side_of_the_reference_is_refused(contact_m, accepted):
    fit = fit_finger_stiffness(_squeezes(width_m=contact_m), object_width_m=WIDTH_M)
    assert bool(fit) is accepted, fit.reason
    if not accepted:
        assert fit.reason.startswith(f"the fingers touch at {contact_m * 1e3:.1f} mm")


def test_the_uncertainty_limit_is_the_one_given():
    fit = fit_finger_stiffness(_squeezes(miss_m=2e-6), object_width_m=WIDTH_M, max_relative_se=1.0)
    relative = fit.stiffness_se_n_per_m / fit.stiffness_n_per_m
    assert fit_finger_stiffness(_squeezes(miss_m=2e-6), object_width_m=WIDTH_M, max_relative_se=relative * 1.05)
    refused = fit_finger_stiffness(_squeezes(miss_m=2e-6), object_width_m=WIDTH_M, max_relative_se=relative * 0.95)
    assert not refused and refused.reason.startswith("too uncertain")


# --------------------------------------------------------------------------- squeezing, faked


class _Readings:
    def __init__(self, value):
        self.value = np.asarray(value, dtype=np.float64)

    def __len__(self):
        return self.value.size


class Hand:
    """Records moves and grasps; ``widths`` delivers ``stale`` first, then the width held."""

    def __init__(self, *, max_width_m=0.08, moves_ok=True, stale=(0.07,), widths=(WIDTH_M,), read_width=None):
        self.max_width_m, self.moves_ok = max_width_m, moves_ok
        self.moves, self.grasps = [], []
        self.queue = [list(stale), list(widths)]
        self.held = list(widths)
        self.read_width_m = read_width

    def move(self, width_m, *, speed_m_s=None):
        self.moves.append(width_m)
        return self.moves_ok

    def grasp(self, width_m, *, speed_m_s=None, force_n=None, epsilon_inner_m=None, epsilon_outer_m=None):
        self.grasps.append((width_m, force_n))
        self.queue = [[0.07], list(self.held)]  # the squeeze's approach, then the width held
        return True

    def widths(self, *, timeout_s=0.0):
        return _Readings(self.queue.pop(0) if self.queue else self.held)

    def read_width(self):
        return 0.0, self.read_width_m


class Cell:
    """Delivers ``stale`` first (the forces before the hold), then ``held``."""

    def __init__(self, stale, held):
        self.reads = [stale]
        self.held = held

    def read(self, timeout_s=None):
        return _Readings(self.reads.pop(0) if self.reads else self.held)


def _squeeze(hand, cell, **kw):
    base = dict(object_width_m=WIDTH_M, forces_n=[10.0], repeats=1, configured_stiffness_n_per_m=2.0e3,
                speed_m_s=0.05, settle_s=0.0, average_s=0.0)
    return squeeze_reference(hand, cell, **{**base, **kw})


def test_a_squeeze_averages_the_force_and_width_held_not_those_before():
    (squeeze,) = _squeeze(Hand(), Cell([0.0, 0.0], [4.0, 6.0]))
    assert squeeze.force_n == 5.0 and squeeze.force_std_n == 1.0 and squeeze.width_m == WIDTH_M


def test_a_squeeze_with_no_width_stream_reads_the_width_once():
    hand = Hand(widths=(), read_width=0.049)
    (squeeze,) = _squeeze(hand, Cell([0.0], [3.0]))
    assert squeeze.width_m == 0.049


def test_the_fingers_open_no_wider_than_the_hand_and_again_after_the_last_squeeze():
    hand = Hand(max_width_m=0.055)
    _squeeze(hand, Cell([0.0], [3.0]), forces_n=[10.0, 20.0])
    assert hand.moves == [0.055, 0.055, 0.055]


def test_a_hand_that_cannot_open_before_a_squeeze_is_an_error_naming_the_width():
    with pytest.raises(gripper_calibration.DeviceError, match=r"could not open to 60.0 mm before a squeeze"):
        _squeeze(Hand(moves_ok=False), Cell([0.0], [3.0]))


def test_a_force_past_what_the_configured_fingers_can_bend_is_commanded_to_a_closed_hand():
    hand = Hand()
    _squeeze(hand, Cell([0.0], [3.0]), forces_n=[200.0])  # 200 N / 2 kN/m = 100 mm: past closed
    assert hand.grasps == [(0.0, 200.0)]


# --------------------------------------------------------------------------- the command's checks


@pytest.fixture
def settings(tmp_path):
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, {"load_cell.backend": "tcp"})
    return load_settings(path)


def _args(**kw):
    return argparse.Namespace(**{**dict(object_width_mm=50.0, repeats=1, levels=4, max_force_n=None), **kw})


@pytest.mark.parametrize("width_mm", [0.0, -5.0, 80.0, 95.0, math.nan])
def test_a_reference_width_outside_the_hands_opening_is_refused_naming_it(settings, width_mm):
    with pytest.raises(gripper_calibration.InvalidCommandError, match=r"--object-width-mm .*: expected a width "
                                                                       r"between 0 and the gripper's 80 mm"):
        gripper_calibration._check(_args(object_width_mm=width_mm), settings)


@pytest.mark.parametrize("force_n", [0.0, -10.0, math.nan])
def test_a_largest_force_that_is_not_positive_is_refused(settings, force_n):
    with pytest.raises(gripper_calibration.InvalidCommandError, match=r"expected a force in \(0, 140\] N"):
        gripper_calibration._check(_args(max_force_n=force_n), settings)


def test_no_sweep_at_all_is_refused(settings):
    with pytest.raises(gripper_calibration.InvalidCommandError, match=r"--repeats 0 --levels 4"):
        gripper_calibration._check(_args(repeats=0), settings)


def test_without_a_largest_force_the_grippers_target_force_is_the_top(settings):
    _, forces = gripper_calibration._check(_args(max_force_n=None), settings)
    assert forces[-1] == settings.gripper.target_force_n and forces[0] == settings.gripper.target_force_n / 4


# --------------------------------------------------------------------------- the command, devices faked


class Rig:
    """A hand squeezing a reference of WIDTH_M with fingers of stiffness K, and a cell reading the force;
    ``miss_m``: how far each width reads alternately off that (a wobbly reference)."""

    def __init__(self, *, miss_m=0.0, cell_fails=False):
        self.force_n, self.squeezes, self.miss_m, self.cell_fails = 0.0, 0, miss_m, cell_fails
        self.closed = []

    def make_gripper(self, settings):
        rig = self

        class Gripper:
            max_width_m = settings.max_width_m

            def connect(self):
                return self

            def move(self, width_m, *, speed_m_s=None):
                rig.force_n = 0.0
                return True

            def grasp(self, width_m, *, speed_m_s=None, force_n=None, epsilon_inner_m=None, epsilon_outer_m=None):
                rig.force_n = force_n
                rig.squeezes += 1
                return True

            def widths(self, *, timeout_s=0.0):
                miss = rig.miss_m if rig.squeezes % 2 else -rig.miss_m
                return _Readings([WIDTH_M - rig.force_n / K + miss])

            def close(self):
                rig.closed.append("gripper")

        return Gripper()

    def make_load_cell(self, settings):
        rig = self

        class LoadCell:
            def connect(self):
                if rig.cell_fails:
                    raise gripper_calibration.DeviceError("load cell: connection refused")
                return self

            def tare(self):
                pass

            def read(self, timeout_s=None):
                return _Readings([rig.force_n])

            def close(self):
                rig.closed.append("cell")

        return LoadCell()


@pytest.fixture
def rig_path(tmp_path, monkeypatch):
    path = tmp_path / "rig.toml"
    shutil.copy(default_settings_path(), path)
    update_settings_file(path, {"load_cell.backend": "tcp", "load_cell.address": "tcp://10.0.0.7:5601"})
    return path


def _run(path, rig, monkeypatch, **kw):
    monkeypatch.setattr(gripper_calibration, "make_gripper", rig.make_gripper)
    monkeypatch.setattr(gripper_calibration, "make_load_cell", rig.make_load_cell)
    args = argparse.Namespace(**{**dict(settings=str(path), object_width_mm=50.0, repeats=2, levels=3, max_force_n=30.0,
                                        settle_s=0.0, average_s=0.0, max_se_percent=5.0, json=False), **kw})
    return gripper_calibration.run(args)


def test_the_stiffness_fitted_is_written_to_four_figures(rig_path, monkeypatch):
    rig = Rig()
    assert _run(rig_path, rig, monkeypatch) == 0
    assert load_settings(rig_path).gripper.finger_stiffness_n_per_m == pytest.approx(K, rel=1e-4)
    assert sorted(rig.closed) == ["cell", "gripper"]


def test_the_uncertainty_limit_given_on_the_command_line_is_the_one_applied(rig_path, monkeypatch, capsys):
    before = rig_path.read_bytes()
    assert _run(rig_path, Rig(miss_m=2e-6), monkeypatch, max_se_percent=0.1) == 1
    assert rig_path.read_bytes() == before
    assert "gripper refused: too uncertain" in capsys.readouterr().err
    assert _run(rig_path, Rig(miss_m=2e-6), monkeypatch, max_se_percent=20.0) == 0


def test_a_load_cell_that_cannot_connect_names_where_it_is_read_and_both_devices_are_closed(rig_path, monkeypatch):
    rig = Rig(cell_fails=True)
    with pytest.raises(gripper_calibration.DeviceError,
                       match=r"connection refused: check tcp://10.0.0.7:5601 \(`load_cell.address`\)"):
        _run(rig_path, rig, monkeypatch)
    assert sorted(rig.closed) == ["cell", "gripper"]
