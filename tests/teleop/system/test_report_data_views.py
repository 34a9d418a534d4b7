"""What ``teleop report`` gathers of each grasp (:mod:`teleop.system.report_data`): the messages read
field by field, which estimate is final and which rendering the display settled on, the time origin,
the log's calibrations checked against their sensors, and the tactile moments: which frames, at what
force, on whose segment, and what is noted when a finger cannot be shown."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.session_logs import ListedLog, logged

import teleop.system.report_data as report_data
from estimator.errors import EstimatorError
from estimator.measurements import REFERENCE_GUARD_S, reference_indices
from estimator.perception.calibration import load_calibration
from estimator.settings import estimator_settings
from teleop.catalogue import load_catalogue
from teleop.settings import load_settings
from teleop.sim.grasp import simulate_grasp
from teleop.system.report_data import (
    MOMENTS,
    DisplayPoint,
    EstimatePoint,
    GraspView,
    grasp_messages,
    log_calibrations,
    tactile_moments,
)


def _display(t_s: float, grasp_id: str | None = "g", **fields) -> SimpleNamespace:
    body = {"phase": "active", "stiffness": 0.25, "E_pa": 1e5, "rigid": False, "unknown": False,
            "provisional": False, **fields}
    return logged("display", t_s, grasp_id=grasp_id, **body)


def test_messages_are_read_field_by_field_and_the_idle_display_belongs_to_no_grasp():
    reader = ListedLog([
        _display(0.5, None, phase="idle", stiffness=0.0, E_pa=None),  # between grasps
        logged("grasp_event", 1.0, event="start", object_name="duck"),
        logged("grasp_event", 1.1, event="loading_end", object_name=None),
        logged("estimate", 1.5, E_pa=2e6, interval_pa=[1e6, None], state="lower_bound", reason="why",
                provisional=0, method="auto"),
        _display(1.6, stiffness=1.0, E_pa=6.75e6, rigid=1, unknown=0, provisional=0),
        _display(1.7, stiffness=0.0, E_pa=None, rigid=False, unknown=True, provisional=True, phase="fading"),
    ])
    views, recorded = grasp_messages(reader)
    assert recorded and list(views) == ["g"]
    (view,) = views.values()
    assert view.object_name == "duck"
    assert view.estimates == [EstimatePoint(1.5, 2e6, (1e6, None), "lower_bound", "why", False, "auto")]
    assert view.display == [DisplayPoint(1.6, "active", 1.0, 6.75e6, True, False, False),
                            DisplayPoint(1.7, "fading", 0.0, None, False, True, True)]
    only_estimates = ListedLog([logged("estimate", 1.5, E_pa=None, interval_pa=[None, None], state="insufficient_data",
                                      reason="", provisional=True, method="series")])
    assert grasp_messages(only_estimates)[1] is False  # a log from before display messages


def test_the_final_estimate_is_the_last_non_provisional_one():
    view = GraspView("g")
    assert view.final is None
    view.estimates = [EstimatePoint(1.0, 1e6, (None, None), "ok", "", False, "auto"),
                      EstimatePoint(2.0, 2e6, (None, None), "ok", "", False, "auto"),
                      EstimatePoint(3.0, 3e6, (None, None), "ok", "", True, "series")]
    assert view.final.e_pa == 2e6


def _shown(t_s: float, *, phase: str = "active", provisional: bool = False) -> DisplayPoint:
    return DisplayPoint(t_s, phase, 0.1 * t_s, 1e5 * t_s, False, False, provisional)


@pytest.mark.parametrize(("display", "settled"), [
    ([_shown(1.0, provisional=True), _shown(2.0), _shown(3.0, provisional=True), _shown(4.0, phase="fading")], 2.0),
    ([_shown(1.0, provisional=True), _shown(2.0, provisional=True), _shown(3.0, phase="stale")], 2.0),
    ([_shown(1.0, phase="stale"), _shown(2.0, phase="fading")], 2.0),
    ([], None),
])
def test_the_display_settled_on_its_last_active_final_rendering_else_its_last_active_else_its_last(display,
                                                                                                  settled):
    view = GraspView("g")
    view.display = display
    assert (view.rendered.t_s if view.rendered else None) == settled


def test_the_time_origin_is_the_start_event_else_the_first_message():
    view = GraspView("g")
    assert view.t0_s == 0.0
    view.estimates = [EstimatePoint(5.0, None, (None, None), "insufficient_data", "", True, "series")]
    view.display = [_shown(3.0), _shown(4.0)]
    assert view.t0_s == 3.0
    view.start_s = 2.5
    assert view.t0_s == 2.5


@pytest.fixture(scope="module")
def settings():
    return load_settings()


@pytest.fixture(scope="module")
def duck(settings):
    objects = {o.name: o for o in load_catalogue()}
    record, _ = simulate_grasp(objects["rubber_duck"], settings=settings, rng=np.random.default_rng(4), seed=4)
    # as the log's export gives it: the grasp's start event
    return dataclasses.replace(record, events={**record.events, "grasp_start": record.events["command_grasp"]})


def test_a_views_start_is_the_records_grasp_start_event(duck):
    start = duck.events["command_grasp"] + 0.25
    record = dataclasses.replace(duck, events={**duck.events, "grasp_start": start})
    view = GraspView("g")
    view.take(record, "")
    assert view.start_s == start and view.t0_s == start and view.record is record


def _info(attachments: dict[str, bytes]) -> SimpleNamespace:
    return SimpleNamespace(attachments=attachments)


def test_a_calibration_made_for_another_sensors_grid_is_refused_with_the_reason(settings, tmp_path):
    left = next(s for s in settings.sensors if s.finger == "left")
    right = next(s for s in settings.sensors if s.finger == "right")
    fitted = load_calibration(left.calibration)
    other = dataclasses.replace(fitted, pixel_pitch_m=2 * fitted.pixel_pitch_m).save(tmp_path / "other.npz")
    name = f"calibration/right/{Path(right.calibration).name}"
    found = log_calibrations(_info({f"calibration/left/{Path(left.calibration).name}": Path(left.calibration)
                                    .read_bytes(), name: Path(other).read_bytes()}), settings)
    assert found["left"].pixel_pitch_m == fitted.pixel_pitch_m
    assert isinstance(found["right"], str) and found["right"].startswith(f"attachment {name}: ")
    assert "pixel pitch" in found["right"]


def test_moment_frames_are_the_last_reference_frame_mid_loading_and_the_last_loading_frame():
    t = np.arange(20) * 0.1
    segment = SimpleNamespace(t_onset_s=0.8, t_peak_s=1.6, frame_index=np.arange(8, 17))
    assert report_data._moment_indices(t, segment, np.arange(0, 6), dropped=0) == [5, 12, 16]
    # frames the stream dropped before the segment's first: its positions count from the first kept
    shifted = SimpleNamespace(t_onset_s=1.0, t_peak_s=1.8, frame_index=np.arange(8, 17) - 2)
    assert report_data._moment_indices(t, shifted, np.arange(0, 8), dropped=4) == [7, 14, 18]
    # no frame in the loading phase: the frames nearest halfway and the peak, of all of them
    empty = SimpleNamespace(t_onset_s=0.8, t_peak_s=1.22, frame_index=np.array([], dtype=int))
    assert report_data._moment_indices(t, empty, np.arange(0, 6), dropped=0) == [5, 10, 12]
    # frames the estimator left out of the loading phase are never its middle
    gapped = SimpleNamespace(t_onset_s=0.8, t_peak_s=1.6, frame_index=np.array([8, 9, 10, 16]))
    assert report_data._moment_indices(t, gapped, np.arange(0, 6), dropped=0) == [5, 10, 16]


class _Segment:
    def __init__(self, name: str, ok: bool = True):
        self.name, self.ok, self.reason = name, ok, f"{name}: no contact"

    def __bool__(self) -> bool:
        return self.ok


def test_the_segment_is_the_estimating_fingers_and_a_grasp_without_loading_says_so(settings, monkeypatch):
    segments = {"left": _Segment("left"), "right": _Segment("right")}
    monkeypatch.setattr(report_data, "measure_grasp",
                        lambda record, *, settings, tactile: SimpleNamespace(segment=segments[settings.sensing.finger]))
    monkeypatch.setattr(report_data, "_finger_moments", lambda record, measured, *, calibration: [])
    record = SimpleNamespace(frames=(SimpleNamespace(finger="left"), SimpleNamespace(finger="right")))
    # the right finger (markers) estimating, its depth on the full grid
    on_right = dataclasses.replace(settings, sensing=dataclasses.replace(settings.sensing, finger="right"))
    on_right = on_right.with_section(dataclasses.replace(estimator_settings(settings), depth_binning=1))
    for estimating in (settings, on_right):
        view = GraspView("g", record=record)
        tactile_moments(view, settings=estimating, calibrations={})
        assert view.segment is segments[estimating.sensing.finger]
    segments["right"].ok = False
    view = GraspView("g", record=record)
    tactile_moments(view, settings=on_right, calibrations={})
    assert view.notes == ["no loading phase: right: no contact"] and not view.moments


def test_a_grasp_the_estimator_cannot_measure_is_a_note_not_the_reports_end(settings, monkeypatch):
    def fails(record, *, settings, tactile):
        raise EstimatorError("frame times not increasing")

    monkeypatch.setattr(report_data, "measure_grasp", fails)
    view = GraspView("g", record=SimpleNamespace(frames=(SimpleNamespace(finger="left"),)))
    tactile_moments(view, settings=settings, calibrations={})
    assert view.notes == ["not measured: frame times not increasing"] and view.segment is None and not view.moments


def test_moments_are_taken_around_contact_with_the_force_at_each_frame(duck, settings):
    view = GraspView("g")
    view.take(duck, "")
    tactile_moments(view, settings=settings, calibrations={f: "none in the log" for f in ("left", "right")})
    assert [(m.finger, m.name) for m in view.moments] == [(f, n) for f in ("left", "right") for n in MOMENTS]
    segment = view.segment  # the estimating (left) finger's
    onset, peak, loading = segment.t_onset_s, segment.t_peak_s, segment.frame_index
    for finger in ("left", "right"):
        stream = duck.stream(finger)
        before, mid, top = (m for m in view.moments if m.finger == finger)
        reference = reference_indices(stream.t_s, onset - REFERENCE_GUARD_S)
        assert before.t_s == stream.t_s[reference[-1]]  # the last frame of the no-contact reference
        assert before.t_s < onset <= mid.t_s < top.t_s
        if finger == "left":
            assert top.t_s == stream.t_s[loading[-1]]  # the estimator's peak frame
            halfway = loading[np.argmin(np.abs(stream.t_s[loading] - 0.5 * (onset + peak)))]
            assert mid.t_s == stream.t_s[halfway]
        for moment in (before, mid, top):
            assert moment.force_n == pytest.approx(np.interp(moment.t_s, duck.force_n.t_s, duck.force_n.value))
        assert before.force_n < 0.2 * top.force_n and mid.force_n < top.force_n


def test_a_finger_whose_frames_do_not_decode_is_noted_and_the_other_is_shown(duck, settings):
    left, right = duck.frames
    garbage = dataclasses.replace(left, encoded=(b"not an image",) * len(left.encoded))
    view = GraspView("g")
    view.take(dataclasses.replace(duck, frames=(garbage, right)), "")
    tactile_moments(view, settings=settings, calibrations={f: "none in the log" for f in ("left", "right")})
    assert any(note.startswith(f"finger {left.finger!r}: finger {left.finger!r} frame ")
               and "data does not decode" in note for note in view.notes), view.notes
    assert {m.finger for m in view.moments} == {right.finger} and len(view.moments) == len(MOMENTS)


def test_a_finger_without_a_frame_before_contact_is_noted_and_the_other_is_shown(duck, settings):
    left, right = duck.frames
    onset = duck.events["command_grasp"]  # the left frames from 1 s after it: none before the contact
    late = left.t_s > onset + 1.0
    left = dataclasses.replace(left, t_s=left.t_s[late], encoded=tuple(np.asarray(left.encoded, dtype=object)[late]))
    view = GraspView("g")
    view.take(dataclasses.replace(duck, frames=(left, right)), "")
    tactile_moments(view, settings=settings, calibrations={f: "none in the log" for f in ("left", "right")})
    assert "finger 'left': no frame before the contact onset" in view.notes
    assert {m.finger for m in view.moments} == {"right"}


def test_markers_are_masked_out_of_the_depth_of_a_finger_that_has_them(duck, settings, monkeypatch):
    masks = []

    def reconstruct(image, reference, calibration, *, marker_mask=None):
        masks.append(marker_mask)
        return np.zeros(image.shape[:2])

    monkeypatch.setattr(report_data, "reconstruct_depth", reconstruct)
    calibrations = {s.finger: load_calibration(s.calibration) for s in settings.sensors}
    view = GraspView("g")
    view.take(duck, "")
    tactile_moments(view, settings=settings, calibrations=calibrations)
    assert not view.notes and len(masks) == 2 * len(MOMENTS)
    # the left finger's gel has no markers, the right one's has (the shipped settings)
    assert [mask is None for mask in masks] == [True] * len(MOMENTS) + [False] * len(MOMENTS)
    assert all(mask.any() for mask in masks[len(MOMENTS):])
