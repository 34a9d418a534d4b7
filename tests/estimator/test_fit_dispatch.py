"""Each analytical method runs its own fit, and one named in ``METHODS`` without its fit is an error
naming it, never another method's figure under its name."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import estimator.analytical as analytical
import estimator.measurements as measurements
from estimator.errors import FitError
from estimator.measure import estimate_grasp
from estimator.measurements import estimate_measurements
from teleop.record import read_record
from teleop.settings import load_settings

RECORD = Path(__file__).resolve().parents[2] / "estimator" / "models" / "reference.grasp"


def test_every_method_runs_its_own_fit(measured):
    estimates = {m: estimate_measurements(measured, m) for m in analytical.METHODS}
    assert all(e.method == m for m, e in estimates.items())
    figures = [(e.state, e.e_pa) for e in estimates.values()]
    assert len(set(figures)) == len(figures), estimates


def test_a_method_without_its_row_is_an_error_naming_it(measured, monkeypatch):
    monkeypatch.setattr(analytical, "METHODS", (*analytical.METHODS, "fake_fit"))
    with pytest.raises(FitError, match="'fake_fit' has no row in FIT_READS"):
        estimate_measurements(measured, "fake_fit")
    with pytest.raises(FitError, match="'fake_fit' has no row in FIT_READS"):  # before the record is measured
        estimate_grasp(read_record(RECORD), "fake_fit", settings=load_settings())


@pytest.mark.parametrize("depth", [False, True])
def test_a_method_without_its_branch_is_an_error_naming_it(measured, monkeypatch, depth):
    monkeypatch.setattr(analytical, "METHODS", (*analytical.METHODS, "fake_fit"))
    monkeypatch.setitem(measurements.FIT_READS, "fake_fit",
                        measurements.FitReads(depth=depth, onset_width=True, approach=True))
    with pytest.raises(FitError, match="'fake_fit' has no branch in _fit"):
        estimate_measurements(measured, "fake_fit")


def test_every_method_has_its_row():
    assert set(measurements.FIT_READS) == set(analytical.METHODS)
    assert measurements.TACTILE_METHODS == ("elastic", "hertz", "series")


def test_onset_width_guard_refuses_the_fits_normalised_by_it(measured):
    no_width = replace(measured, segment=replace(measured.segment, onset_width_m=float("nan")))
    refused = {m for m in analytical.METHODS
               if "no positive width at the contact onset" in estimate_measurements(no_width, m).reason}
    assert refused == {"no_tactile", "elastic"}


def test_an_unread_width_bounds_the_fits_on_the_approach(measured):
    unread = replace(measured, segment=replace(measured.segment, flags=("width_unread",)))
    for method in analytical.METHODS:
        before, after = estimate_measurements(measured, method), estimate_measurements(unread, method)
        if before.state == "ok" and method in ("no_tactile", "series"):
            assert after.state == "lower_bound" and np.isclose(after.e_pa, before.interval_pa[0]), method
        else:
            assert (after.state, after.e_pa) == (before.state, before.e_pa), method
