"""Audit of :mod:`teleop.rig.load_cell_calibration`: the fit's figures and refusals at their limits,
reading a level, waiting for a mass, and the command's steps with a fake cell."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest

from teleop.errors import DeviceTimeoutError, TeleopError
from teleop.rig import load_cell_calibration
from teleop.rig.load_cell_calibration import (
    Level,
    fit_load_cell,
    load_cell_source,
    read_level,
    wait_for_level,
)
from teleop.settings import default_settings_path, load_settings

SLOPE = 4.0e4  # counts per N
TARE = 1000.0


def _at(mass_g, *, miss_n=0.0, std=5.0, n=100):
    return Level(mass_g, TARE + SLOPE * (mass_g * 1e-3 * 9.80665 + miss_n), std, n)


def test_a_kilogram_weighs_standard_gravity_in_newtons():
    assert Level(1000.0, 0.0, 0.0, 1).force_n == 9.80665


@pytest.mark.parametrize("mass_g", [0.0, -100.0, float("nan")])
def test_a_loaded_level_without_a_positive_mass_is_refused_naming_the_masses(mass_g):
    with pytest.raises(TeleopError, match=r"masses \[.*\] g: expected at least one, each > 0 g"):
        fit_load_cell(_at(0.0), [_at(500.0), Level(mass_g, 5000.0, 1.0, 10)])


def test_counts_per_newton_is_the_least_squares_line_through_the_tare():
    # Two masses off the line either way: the slope weights each by its force (sum F c / sum F^2).
    loaded = [_at(200.0, miss_n=0.01), _at(1000.0, miss_n=-0.02)]
    fit = fit_load_cell(_at(0.0), loaded, max_residual_fraction=1.0)
    force = np.array([0.2, 1.0]) * 9.80665
    change = SLOPE * (force + [0.01, -0.02])
    assert fit.counts_per_n == pytest.approx(force @ change / (force @ force), rel=1e-12)
    assert fit.tare_counts == TARE


def test_the_residual_is_the_largest_miss_at_any_mass():
    loaded = [_at(200.0, miss_n=0.05), _at(500.0), _at(1000.0)]
    fit = fit_load_cell(_at(0.0), loaded, max_residual_fraction=1.0)
    force = np.array([0.2, 0.5, 1.0]) * 9.80665
    change = SLOPE * (force + [0.05, 0.0, 0.0])
    slope = force @ change / (force @ force)
    assert fit.residual_n == pytest.approx(np.max(np.abs(change / slope - force)), rel=1e-9)
    assert fit.residual_fraction == pytest.approx(fit.residual_n / (1.0 * 9.80665), rel=1e-12)


def test_the_noise_is_the_std_of_single_readings_pooled_over_all_levels_by_their_readings():
    tare, loaded = _at(0.0, std=10.0, n=301), [_at(1000.0, std=20.0, n=101)]
    fit = fit_load_cell(tare, loaded, max_noise_fraction=1.0)
    pooled = np.sqrt((300 * 10.0**2 + 100 * 20.0**2) / 400)
    assert fit.noise_n == pytest.approx(pooled / SLOPE, rel=1e-9)


@pytest.mark.parametrize("moved, std", [(1.5, 0.0), (40.0, 10.0), (-40.0, 10.0)])
def test_a_mass_moving_the_counts_within_the_noise_or_two_counts_reads_no_change(moved, std):
    fit = fit_load_cell(Level(0.0, TARE, std, 100), [_at(1000.0, std=std), Level(100.0, TARE + moved, std, 100)])
    assert not fit and fit.reason.startswith("the 100 g mass reads no change"), fit.reason


def test_a_mass_moving_the_counts_just_past_the_noise_is_measured():
    # 5 x 1 count of noise: 5.5 counts is a change (the line then misses it: a separate refusal).
    fit = fit_load_cell(Level(0.0, TARE, 1.0, 100), [Level(0.01, TARE + 5.5, 1.0, 100)],
                        max_noise_fraction=1.0, max_residual_fraction=1.0)
    assert fit, fit.reason


def test_counts_that_cancel_to_no_slope_are_refused_as_falling():
    # 100 g reads +k, 200 g reads -k/2: the line through the tare is flat.
    fit = fit_load_cell(_at(0.0), [Level(100.0, TARE + 2000.0, 5.0, 100), Level(200.0, TARE - 1000.0, 5.0, 100)])
    assert fit.counts_per_n == 0.0
    assert not fit and fit.reason.startswith("the counts fall under load"), fit.reason


def test_the_linearity_limit_is_the_one_given():
    loaded = [_at(200.0, miss_n=0.05), _at(1000.0)]
    fraction = fit_load_cell(_at(0.0), loaded, max_residual_fraction=1.0).residual_fraction
    assert fit_load_cell(_at(0.0), loaded, max_residual_fraction=fraction * 1.05)
    refused = fit_load_cell(_at(0.0), loaded, max_residual_fraction=fraction * 0.95)
    assert not refused and refused.reason.startswith("non-linear")


# --------------------------------------------------------------------------- the cell


def test_the_source_named_is_the_port_or_the_address_of_the_backend():
    settings = load_settings(default_settings_path()).load_cell
    assert load_cell_source(dataclasses.replace(settings, backend="serial", port="/dev/ttyUSB3")) == \
        "/dev/ttyUSB3 (`load_cell.port`)"
    assert load_cell_source(dataclasses.replace(settings, backend="serial", port="")) == "(no port) (`load_cell.port`)"
    assert load_cell_source(dataclasses.replace(settings, backend="tcp", address="tcp://10.0.0.7:5601")) == \
        "tcp://10.0.0.7:5601 (`load_cell.address`)"
    assert load_cell_source(dataclasses.replace(settings, backend="tcp", address="tcp://pi:s3cret@10.0.0.7:5601")) \
        == "tcp://pi:***@10.0.0.7:5601 (`load_cell.address`)"


def test_the_cell_is_read_in_raw_counts_whatever_its_calibration(monkeypatch):
    made = []

    class Cell:
        def connect(self):
            return self

    monkeypatch.setattr(load_cell_calibration, "make_load_cell", lambda settings: made.append(settings) or Cell())
    settings = dataclasses.replace(load_settings(default_settings_path()).load_cell, backend="serial",
                                   port="/dev/ttyUSB3", counts_per_n=41000.0, tare_counts=-5000)
    load_cell_calibration.connect_counts_cell(settings)
    assert made[0].counts_per_n == 1.0 and made[0].tare_counts == 0 and made[0].port == "/dev/ttyUSB3"


class ChunkCell:
    """Each read() returns the next chunk (the last one repeats); ``None``: a timeout."""

    settings = load_settings(default_settings_path()).load_cell

    def __init__(self, *chunks):
        self.chunks = list(chunks)
        self.closed = False

    def read(self, timeout_s=None):
        chunk = self.chunks.pop(0) if len(self.chunks) > 1 else self.chunks[0]
        if chunk is None:
            raise DeviceTimeoutError("nothing")
        return argparse.Namespace(value=np.asarray(chunk, dtype=np.float64))

    def close(self):
        self.closed = True


def test_a_level_is_the_mean_and_sample_std_of_the_readings_after_the_first_read():
    level = read_level(ChunkCell([9e9], [10.0, 14.0], [10.0, 14.0]), 50.0, duration_s=0.0)
    assert level == Level(50.0, 12.0, pytest.approx(np.std([10.0, 14.0], ddof=1)), 2)


def test_a_level_of_one_reading_has_no_scatter():
    assert read_level(ChunkCell([0.0], [7.0]), 50.0, duration_s=0.0).std_counts == 0.0


def test_a_cell_that_times_out_names_where_it_is_read_and_the_setting():
    with pytest.raises(DeviceTimeoutError, match=r"load cell: no reading from .* within 1.0 s: check the cable"):
        read_level(ChunkCell(None), 50.0, duration_s=0.0)


def test_a_mass_taken_off_counts_as_a_new_level_too():
    wait_for_level(ChunkCell([1000.0, 900.0, 900.0]), Level(0.0, 1000.0, 1.0, 100), 20.0, timeout_s=0.5)


def test_a_step_of_the_threshold_or_less_is_not_a_new_level():
    with pytest.raises(DeviceTimeoutError, match=r"stayed within 20 counts of the 0 g level"):
        wait_for_level(ChunkCell([1020.0, 1020.0, 1020.0]), Level(0.0, 1000.0, 1.0, 100), 20.0, timeout_s=0.02)


# --------------------------------------------------------------------------- the command's steps


class PlacingCell(ChunkCell):
    """Reads ``levels[k]`` once the k-th mass was asked for (``say("place ...")``)."""

    def __init__(self, monkeypatch, levels):
        super().__init__([levels[0]])
        self.levels, self.placed = levels, 0
        monkeypatch.setattr(load_cell_calibration, "say", self.say)

    def say(self, text):
        if text.startswith("place "):
            self.placed += 1

    def read(self, timeout_s=None):
        return argparse.Namespace(value=np.full(3, float(self.levels[self.placed])))


def _args(**kw):
    base = dict(settings="unused", mass_g=[100.0], average_s=0.0, settle_s=0.0, place_timeout_s=0.05,
                max_residual_percent=1.0, max_noise_percent=0.5, json=False)
    return argparse.Namespace(**{**base, **kw})


def test_a_noiseless_tare_still_needs_a_step_of_20_counts_for_a_mass(monkeypatch):
    cell = PlacingCell(monkeypatch, [0.0, 15.0])
    with pytest.raises(DeviceTimeoutError, match="no new load within"):
        load_cell_calibration._measure(cell, _args(), ask=lambda _p: "")


def test_each_mass_must_depart_from_the_mass_before_not_from_the_tare(monkeypatch):
    # The second mass was never placed: the cell still reads the first, far from the tare.
    cell = PlacingCell(monkeypatch, [0.0, 5000.0, 5000.0])
    with pytest.raises(DeviceTimeoutError, match="of the 100 g level"):
        load_cell_calibration._measure(cell, _args(mass_g=[100.0, 200.0]), ask=lambda _p: "")


def test_an_answer_that_is_no_number_is_asked_again(monkeypatch, capsys):
    monkeypatch.setattr(load_cell_calibration, "read_level", lambda cell, mass_g, duration_s: Level(mass_g, 1.0, 0.0, 1))
    answers = iter(["two hundred", "200", ""])
    levels = load_cell_calibration._interactive_levels(None, _args(), lambda _p: next(answers))
    assert [lv.mass_g for lv in levels] == [200.0]
    assert "not a mass in grams: 'two hundred'" in capsys.readouterr().err


def test_the_tare_and_slope_written_are_the_fits(absent_cell_rig, monkeypatch):
    cell = PlacingCell(monkeypatch, [-51234.4, -51234.4 + 4.1e4 * 0.5 * 9.80665])
    monkeypatch.setattr(load_cell_calibration, "connect_counts_cell", lambda settings: cell)
    assert load_cell_calibration.run(_args(settings=str(absent_cell_rig), mass_g=[500.0])) == 0
    settings = load_settings(absent_cell_rig).load_cell
    assert settings.tare_counts == -51234 and settings.counts_per_n == pytest.approx(4.1e4, rel=1e-6)
    assert cell.closed


def test_the_linearity_limit_given_on_the_command_line_is_the_one_applied(absent_cell_rig, monkeypatch):
    # 200 g reads 4 % high against 1 kg: the line misses it by 0.7 % of full scale, non-linear at
    # --max-residual-percent 0.5 (though the noise limit is higher).
    force = np.array([0.2, 1.0]) * 9.80665
    cell = PlacingCell(monkeypatch, [0.0, *(4e4 * force * [1.04, 1.0])])
    monkeypatch.setattr(load_cell_calibration, "connect_counts_cell", lambda settings: cell)
    before = absent_cell_rig.read_bytes()
    args = _args(settings=str(absent_cell_rig), mass_g=[200.0, 1000.0], max_residual_percent=0.5, max_noise_percent=2.0)
    assert load_cell_calibration.run(args) == 1
    assert absent_cell_rig.read_bytes() == before


def test_the_cell_is_closed_when_a_mass_is_never_placed(absent_cell_rig, monkeypatch):
    cell = PlacingCell(monkeypatch, [0.0, 0.0])
    monkeypatch.setattr(load_cell_calibration, "connect_counts_cell", lambda settings: cell)
    with pytest.raises(DeviceTimeoutError):
        load_cell_calibration.run(_args(settings=str(absent_cell_rig)))
    assert cell.closed


def test_input_ending_at_a_prompt_is_a_clear_refusal_and_writes_nothing(absent_cell_rig, monkeypatch):
    # Ctrl-D at "Remove everything from the cell" was an EOFError traceback.
    cell = PlacingCell(monkeypatch, [0.0])
    monkeypatch.setattr(load_cell_calibration, "connect_counts_cell", lambda settings: cell)
    monkeypatch.setattr("sys.stdin.isatty", lambda: True)
    before = absent_cell_rig.read_bytes()

    def ask(prompt):
        raise EOFError

    with pytest.raises(load_cell_calibration.SettingsError, match=r"the input ended .* nothing was written"):
        load_cell_calibration.run(_args(settings=str(absent_cell_rig), mass_g=None), ask=ask)
    assert absent_cell_rig.read_bytes() == before and cell.closed
