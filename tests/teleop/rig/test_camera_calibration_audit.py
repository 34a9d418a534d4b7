"""Audit of :mod:`teleop.rig.camera_calibration` with fake devices: the no-contact frame, what a tap's
recording keeps, and what ``run`` writes from the corners' and the latency's fits."""

from __future__ import annotations

import argparse
import contextlib
import json
import time

import numpy as np
import pytest
from support.cameras import FakeFrame, ListCamera

from teleop.errors import DeviceTimeoutError
from teleop.grasp_data import Samples
from teleop.rig import camera_calibration
from teleop.rig.camera_latency import LatencyFit
from teleop.rig.gel_corners import CornerFit
from teleop.settings import load_settings


class ListCell:
    """Delivers each of ``chunks`` in turn (None: a timeout), then times out."""

    def __init__(self, chunks):
        self.chunks = list(chunks)

    def read(self, timeout_s=None):
        chunk = self.chunks.pop(0) if self.chunks else None
        if chunk is None:
            raise DeviceTimeoutError("no sample")
        return chunk() if callable(chunk) else chunk


def test_a_flicker_in_one_reference_frame_drops_out_of_the_no_contact_frame():
    frames = [FakeFrame(0.0, 100)] * 2 + [FakeFrame(0.0, 255)] + [FakeFrame(0.0, 101)] * 2
    frame = camera_calibration.no_contact_frame(ListCamera(frames), settle_frames=0)
    assert (frame == 101).all()


def test_force_samples_queued_before_the_tap_recording_are_dropped():
    stale = Samples(np.array([-3.0, -2.0]), np.array([9.0, 9.0]))
    _, force = camera_calibration.record_tap(ListCamera([]), ListCell([stale]), duration_s=0.02)
    assert len(force) == 0


def test_frames_and_force_stamped_after_the_recording_ended_are_dropped():
    late = time.monotonic() + 1e6
    cell = ListCell([Samples(np.array([late]), np.array([1.0]))])
    frames, force = camera_calibration.record_tap(ListCamera([FakeFrame(late, 7)]), cell, duration_s=0.02)
    assert frames == [] and len(force) == 0


def test_a_load_cell_that_is_late_to_start_is_waited_for_until_the_recording_ends():
    now = lambda: Samples(np.array([time.monotonic()]), np.array([2.0]))  # noqa: E731
    cell = ListCell([None, None, now, now])
    _, force = camera_calibration.record_tap(ListCamera([]), cell, duration_s=0.2)
    assert force.value.tolist() == [2.0, 2.0]


# --------------------------------------------------------------------------- run, its steps faked


def _rig(tmp_path, *, model="wedge", latency_s=0.02, cell="serial"):
    path = tmp_path / "rig.toml"
    path.write_text(f'[sensors.left]\nmodel = "{model}"\ncamera_backend = "opencv"\ncamera_source = "0"\n'
                    f"camera_latency_s = {latency_s}\n\n"
                    f'[sensors.right]\nmodel = "{model}"\ncamera_backend = "opencv"\ncamera_source = "1"\n\n'
                    f'[load_cell]\nbackend = "{cell}"\nport = "/dev/ttyUSB9"\n')
    return path


CORNERS = np.array([[60.0, 70.0], [450.0, 110.0], [50.0, 430.0], [430.0, 380.0]])


@pytest.fixture
def faked(monkeypatch):
    """The camera steps of ``run`` faked: what they were asked, and the fits they give (set per test)."""
    calls = {"cameras": [], "corners": 0, "latency": 0,
             "corner_fit": CornerFit(corners_px=CORNERS, edge_rms_px=0.3, contrast=80.0, bow_px=2.0),
             "latency_fit": LatencyFit(latency_s=0.05, correlation=0.9, force_peak_n=3.0, change_peak=4.0)}

    def make_camera(sensor):
        calls["cameras"].append(sensor.finger)
        return contextlib.nullcontext(argparse.Namespace(sensor=sensor))

    def corners(frame, sensor, png):
        calls["corners"] += 1
        return calls["corner_fit"]

    def latency(camera, settings, duration_s):
        calls["latency"] += 1
        return calls["latency_fit"]

    monkeypatch.setattr(camera_calibration, "make_camera", make_camera)
    monkeypatch.setattr(camera_calibration, "no_contact_frame", lambda camera: None)
    monkeypatch.setattr(camera_calibration, "_declared_size", lambda frame, sensor, path: frame)
    monkeypatch.setattr(camera_calibration, "_corners", corners)
    monkeypatch.setattr(camera_calibration, "_latency", latency)
    return calls


def _run(path, *, finger=None, latency=True, as_json=True):
    return camera_calibration.run(argparse.Namespace(settings=str(path), finger=finger, out_png=None,
                                                     latency=latency, duration_s=1.0, json=as_json))


def test_the_latency_measured_adds_to_the_latency_already_configured(tmp_path, faked, capsys):
    path = _rig(tmp_path, latency_s=0.02)
    assert _run(path) == 0
    sensor = load_settings(path).sensor("left")
    assert sensor.camera_latency_s == pytest.approx(0.07)
    np.testing.assert_allclose(sensor.warp_corners_px, CORNERS)
    report = json.loads(capsys.readouterr().out)
    assert report["latency"]["latency_s"] == pytest.approx(0.05) and report["latency"]["reason"] == ""


def test_a_refused_latency_writes_not_even_the_corners_and_reports_nan_as_null(tmp_path, faked, capsys):
    faked["latency_fit"] = LatencyFit(force_peak_n=0.01, reason="no tap in the force")
    path = _rig(tmp_path)
    before = path.read_bytes()
    assert _run(path) == 1
    assert path.read_bytes() == before
    out, err = capsys.readouterr()
    report = json.loads(out)  # strict JSON: NaN is no JSON number
    assert report["latency"]["latency_s"] is None and report["changes"] == []
    assert "camera refused: latency: no tap in the force" in err


def test_without_latency_the_load_cell_is_not_asked_for_even_if_simulated(tmp_path, faked):
    path = _rig(tmp_path, cell="sim")
    assert _run(path, latency=False, as_json=False) == 0
    assert faked["latency"] == 0 and faked["corners"] == 1
    assert "camera_latency_s = 0.02" in path.read_text()


def test_a_flat_sensor_with_latency_measures_the_latency_and_no_corners(tmp_path, faked):
    path = _rig(tmp_path, model="mini", latency_s=0.0)
    assert _run(path) == 0
    assert faked["corners"] == 0 and faked["latency"] == 1
    assert load_settings(path).sensor("left").camera_latency_s == pytest.approx(0.05)


def test_the_finger_given_is_the_one_calibrated(tmp_path, faked):
    path = _rig(tmp_path)
    assert _run(path, finger="right", latency=False) == 0
    assert faked["cameras"] == ["right"]
    settings = load_settings(path)
    np.testing.assert_allclose(settings.sensor("right").warp_corners_px, CORNERS)
    assert not np.allclose(settings.sensor("left").warp_corners_px, CORNERS)


def test_a_frame_of_the_declared_height_but_another_width_is_refused(tmp_path):
    path = _rig(tmp_path)
    sensor = load_settings(path).sensor("left")
    frame = np.zeros((sensor.raw_height_px, sensor.raw_width_px + 160, 3), np.uint8)
    with pytest.raises(camera_calibration.TeleopError, match=r"gives 800x480 px frames, but raw_width_px x raw_height_px = 640x480"):
        camera_calibration._declared_size(frame, sensor, path)


def test_the_gel_at_rest_is_the_median_of_the_recording_not_its_first_frame(tmp_path, monkeypatch):
    # The tap shows in the first frame: measured against the rest of the recording, it alone changed.
    frames = [FakeFrame(0.1, 180)] + [FakeFrame(0.1 + 0.01 * i, 100) for i in range(1, 40)]
    given = {}

    def measure(frame_t_s, change, force_t_s, force_n):
        given["change"] = np.asarray(change)
        return LatencyFit(reason="not measured here")

    monkeypatch.setattr(camera_calibration, "make_load_cell", lambda settings: contextlib.nullcontext(None))
    monkeypatch.setattr(camera_calibration, "record_tap",
                        lambda camera, cell, duration_s: (frames, Samples(np.zeros(0), np.zeros(0))))
    monkeypatch.setattr(camera_calibration, "measure_latency", measure)
    settings = load_settings(_rig(tmp_path))
    camera = argparse.Namespace(sensor=settings.sensor("left"))
    assert not camera_calibration._latency(camera, settings, 1.0)
    assert given["change"][0] == 80.0 and not given["change"][1:].any()


class Clock:
    """``time.monotonic`` of a recording: each device read takes ``step_s``."""

    def __init__(self, step_s=0.001):
        self.now, self.step_s = 100.0, step_s

    def monotonic(self):
        return self.now

    def tick(self):
        self.now += self.step_s
        return self.now


def test_a_camera_that_always_has_a_frame_does_not_keep_the_recording_past_its_end(monkeypatch):
    # A camera faster than the poll (200 fps and more) never times out: the load cell must still be read,
    # and the recording end on time.
    clock = Clock()
    monkeypatch.setattr(camera_calibration, "time", clock)

    class BusyCamera:
        reads = 0

        def read(self, timeout_s=None):
            self.reads += 1
            if self.reads > 1000:
                raise AssertionError("the camera was still read long after the recording's end")
            return FakeFrame(clock.tick(), 100)

    class Cell:
        def read(self, timeout_s=None):
            return Samples(np.array([clock.tick()]), np.array([1.0]))

    camera = BusyCamera()
    frames, force = camera_calibration.record_tap(camera, Cell(), duration_s=0.1)
    assert camera.reads < 200 and 50 < len(frames) < 150 and len(force) > 0
    assert all(100.0 <= f.t_s <= 100.1 for f in frames) and (force.t_s <= 100.1).all()
