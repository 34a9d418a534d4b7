"""Misused estimator entry points fail with a FitError naming the argument, not an AttributeError."""

from __future__ import annotations

import pytest

from estimator.errors import FitError
from estimator.measure import measure_grasp
from estimator.stream import GraspStream


@pytest.fixture
def record(records):
    return records["steel_ball_bearing"]


@pytest.mark.parametrize("bad", ["records/x.grasp", None])
def test_from_record_refuses_what_is_not_a_record(settings, bad):
    with pytest.raises(FitError, match=r"record: expected a GraspRecord \(teleop\.record\.read_record\), got "):
        GraspStream.from_record(bad, settings=settings)


@pytest.mark.parametrize("bad", ["records/x.grasp", None])
def test_measure_grasp_refuses_what_is_not_a_record(settings, bad):
    with pytest.raises(FitError, match=f"record: expected a GraspRecord .*got {type(bad).__name__}"):
        measure_grasp(bad, settings=settings)


@pytest.mark.parametrize("bad", [None, "configs/settings.toml"])
def test_settings_must_be_settings(record, bad):
    with pytest.raises(FitError, match=f"settings: expected Settings .*got {type(bad).__name__}"):
        GraspStream.from_record(record, settings=bad)
    with pytest.raises(FitError, match="settings: expected Settings"):
        measure_grasp(record, settings=bad)
    with pytest.raises(FitError, match="settings: expected Settings"):
        GraspStream(settings=bad, calibration=None)


def test_methods_as_one_str_is_refused(settings, record):
    with pytest.raises(FitError, match="methods: expected a sequence of method names, got the str 'series'"):
        GraspStream(settings=settings, calibration=None, methods="series")
    with pytest.raises(FitError, match="got the str 'series'"):
        GraspStream.from_record(record, settings=settings, methods="series")
    assert GraspStream.from_record(record, settings=settings, methods=("series",)).methods == ("series",)
