"""``teleop demo``'s run on a stand-in live system (no processes): its JSON (the top-level ``operator``, each
grasp's ``style``), where its text goes, the grasps it names and the operator's style it notes; and the pieces
it prepares with (the scene's plan, the objects' fit, the run folder, the fitted calibration's line)."""

from __future__ import annotations

import argparse
import io
import json
import os
import textwrap
from pathlib import Path
from types import SimpleNamespace

import pytest
from support.outcomes import outcome

import teleop.system.demo as demo
import teleop.system.seat
from teleop.errors import SettingsError
from teleop.settings import default_settings_path, load_settings

RANGE = (5e3, 6.75e6)


class _Seat:
    """The simulated operator's seat: its style is that of the grasp the stand-in system last started."""

    made: list[_Seat] = []

    def __init__(self, system, settings, *, grasps):
        self.system, self.grasps, self.checks, self.error = system, grasps, 0, None
        _Seat.made.append(self)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def style(self) -> str:
        return self.system.current_style

    def check(self) -> None:
        self.checks += 1
        if self.error is not None:
            raise self.error


class _System:
    """A started live system whose grasps give a duck estimated right (rendered within 2x)."""

    made: list[_System] = []
    recording_stopped: str | None = None

    def __init__(self, settings, scene, run_dir, calibration, *, foxglove=None, model=None):
        self.model, self.run_dir = model, run_dir
        self.children = {"node": SimpleNamespace(process=SimpleNamespace(pid=11))}
        self.session_log = run_dir / "session.mcap"
        self.grasp_ids: list[str] = []
        self.on_messages: list = []
        self.current_style = ""
        _System.made.append(self)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def _outcome(self, obj, style):
        o = outcome(obj.name, obj.modulus_pa, {"E_pa": obj.modulus_pa, "state": "ok", "model": "m-1"}, 0.1, 120.0,
                    display_range=RANGE)
        o.obj, o.style = obj, style
        return o

    def grasp(self, grasp_id, index, obj, *, on_message=None, on_update=None):
        self.grasp_ids.append(grasp_id)
        self.on_messages.append(on_message)
        o = self._outcome(obj, "script")
        if on_update is not None:
            on_update(o)
        return o

    def operated_grasp(self, obj, *, on_update=None):
        number = len(self.grasp_ids) + 1
        self.grasp_ids.append(f"operated-{number}")
        o = self._outcome(obj, "operator")
        on_update(o)  # before the robot started it: the seat's style is still the last grasp's
        o.started = True
        self.current_style = f"squeeze {number}"
        on_update(o)
        self.current_style = f"squeeze {number + 1} (next)"  # the operator moved on before the last report
        on_update(o)
        return o


@pytest.fixture
def fake_demo(monkeypatch, tmp_path):
    """``demo.run`` with the live system, the seat and the run folder replaced; gives the parsed arguments."""
    _System.made, _Seat.made = [], []
    monkeypatch.setattr(_System, "recording_stopped", None)
    monkeypatch.setattr(demo, "LiveSystem", _System)
    monkeypatch.setattr(teleop.system.seat, "SimulatedSeat", _Seat)
    monkeypatch.setattr(demo, "prepare_run", lambda args, **kwargs: (tmp_path / "run", tmp_path / "cal.npz"))
    scene = tmp_path / "pair.toml"
    scene.write_text('objects = ["stress_ball", "rubber_duck"]\n')

    def parse(*argv: str) -> argparse.Namespace:
        parser = argparse.ArgumentParser()
        demo.add_arguments(parser)
        return parser.parse_args(["--scene", str(scene), *argv])

    return parse


def test_the_json_of_a_scripted_run_says_script_for_the_run_and_each_grasp_and_is_stdout_alone(fake_demo, capsys,
                                                                                                tmp_path):
    assert demo.run(fake_demo("--json", "--operator", "script")) == 0
    out, err = capsys.readouterr()
    assert len(out.strip().splitlines()) == 1  # the table and the live lines went to stderr
    result = json.loads(out)
    assert result["operator"] == "script" and [g["style"] for g in result["grasps"]] == ["script", "script"]
    assert result["scene"] == "pair" and [g["object"] for g in result["grasps"]] == ["stress_ball", "rubber_duck"]
    assert _System.made[0].grasp_ids == ["pair-001", "pair-002"]  # the scene's name, the grasp's number
    assert result["models"] == {"m-1": 2} and result["recording_stopped"] is None
    assert result["run_dir"] == str(tmp_path / "run") and result["session_log"] == str(tmp_path / "run" / "session.mcap")
    assert result["summary"] == {"grasps": 2, "rendered": 2, "not_rendered": 0,
                                 "mean_error_decades": pytest.approx(0.0, abs=1e-9), "within_2x": 2,
                                 "dangerous_misses": 0}
    assert any(line.startswith("object") for line in err.splitlines())
    assert f"session log: {tmp_path / 'run' / 'session.mcap'}" in err.splitlines()
    assert [line.split()[0] for line in err.splitlines() if line.startswith("[")] == ["[1/2]", "[2/2]"]


def test_the_json_of_a_simulated_operators_run_says_sim_and_each_grasp_operator_with_its_squeeze(fake_demo, capsys):
    assert demo.run(fake_demo("--json")) == 0  # --operator sim: the default
    out, err = capsys.readouterr()
    result = json.loads(out)
    assert [line.split()[0] for line in err.splitlines() if line.startswith("[")] == ["[1/2]", "[2/2]"]
    assert result["operator"] == "sim" and [g["style"] for g in result["grasps"]] == ["operator", "operator"]
    # The style of the grasp as it started: not the last grasp's before it, nor the next one's after it.
    assert [g["operator_style"] for g in result["grasps"]] == ["squeeze 1", "squeeze 2"]
    assert [g["latency_ms"] for g in result["grasps"]] == [None, None]
    seat = _Seat.made[0]
    assert seat.grasps == 2 and seat.checks == 6  # the seat is checked at each update


def test_what_ended_the_simulated_operator_stops_the_demo(fake_demo, monkeypatch):
    class _FailedSeat(_Seat):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.error = RuntimeError("the operator's thread died")

    monkeypatch.setattr(teleop.system.seat, "SimulatedSeat", _FailedSeat)
    with pytest.raises(RuntimeError, match="the operator's thread died"):
        demo.run(fake_demo("--json"))


def test_without_json_the_table_is_on_stdout_and_no_view_leaves_out_the_live_lines(fake_demo, capsys):
    assert demo.run(fake_demo("--operator", "script")) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in out if line.startswith("[")] == ["[1/2]", "[2/2]"]
    assert any(line.startswith("object") for line in out) and out[-1].startswith("session log: ")
    assert demo.run(fake_demo("--operator", "script", "--no-view")) == 0
    out = capsys.readouterr().out.splitlines()
    assert not any(line.startswith("[") for line in out) and any(line.startswith("object") for line in out)


def test_a_stopped_recording_is_said_beside_the_session_log_and_in_the_json(fake_demo, monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(_System, "recording_stopped", "disk full")
    assert demo.run(fake_demo("--json", "--operator", "script")) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["recording_stopped"] == "disk full"
    assert f"session log: {tmp_path / 'run' / 'session.mcap'} (partial: recording stopped: disk full)" in err


def test_the_estimator_gets_the_checked_models_folder_not_the_option_as_typed(fake_demo):
    from estimator.inference.infer import default_model_dir

    typed = os.path.relpath(default_model_dir() / "model.onnx")
    assert demo.run(fake_demo("--json", "--operator", "script", "--model", typed)) == 0
    assert _System.made[0].model == str(default_model_dir().absolute())


def test_run_grasps_passes_each_message_on_and_shows_each_update_and_end():
    shown = []
    view = SimpleNamespace(update=lambda n, o: shown.append(("update", n)), finish=lambda n, o: shown.append(("end", n)))
    system = _System(None, None, Path("run"), None)
    plan = demo.scene_plan("quick")[:2]
    seen = []
    outcomes = list(demo.run_grasps(system, plan, view, "bench", on_message=seen.append))
    assert [o.obj.name for o in outcomes] == [obj.name for _, obj in plan]
    assert system.grasp_ids == ["bench-001", "bench-002"] and system.on_messages == [seen.append, seen.append]
    assert shown == [("update", 1), ("end", 1), ("update", 2), ("end", 2)]


def test_a_scene_plan_repeats_each_object_grasps_per_object_times(tmp_path):
    scene = tmp_path / "twice.toml"
    scene.write_text(textwrap.dedent("""
        objects = ["stress_ball", "rubber_duck"]
        grasps_per_object = 2
    """))
    plan = demo.scene_plan(str(scene))
    assert [(i, obj.name) for i, obj in plan] == [(0, "stress_ball"), (1, "stress_ball"), (2, "rubber_duck"),
                                                  (3, "rubber_duck")]


def test_an_object_at_the_fit_margin_is_refused_and_one_just_under_it_is_not(monkeypatch):
    from teleop.sim import shapes

    settings = load_settings()
    limit = shapes.FIT_MARGIN * settings.gripper.max_width_m
    widths = {"at": limit, "under": limit * (1 - 1e-9)}
    monkeypatch.setattr(shapes, "object_size", lambda obj: None)
    monkeypatch.setattr(shapes, "narrowest_width", lambda obj, size: widths[obj.name])
    objects = [SimpleNamespace(name=name) for name in widths]
    with pytest.raises(SettingsError, match=r"objects 'at' \("):
        demo.check_objects_fit(SimpleNamespace(name="s", objects=objects), settings)
    demo.check_objects_fit(SimpleNamespace(name="s", objects=objects[1:]), settings)


def test_an_out_folder_holding_an_earlier_session_log_is_refused_and_an_empty_one_taken(tmp_path):
    args = argparse.Namespace(settings=str(default_settings_path()), scene="quick", out=str(tmp_path / "a"))
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "session.mcap").write_bytes(b"")
    with pytest.raises(SettingsError, match=r"holds an earlier run \(session.mcap\)"):
        demo.prepare_run(args, prefix="demo", out=io.StringIO())
    (tmp_path / "b").mkdir()
    args.out = str(tmp_path / "b")
    assert demo.prepare_run(args, prefix="demo", out=io.StringIO())[0] == tmp_path / "b"


def test_the_fitted_calibrations_line_goes_where_the_text_goes(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(demo, "configured_calibration", lambda settings: None)
    monkeypatch.setattr(demo, "simulated_calibration", lambda settings, run_dir: run_dir / "fitted.npz")
    args = argparse.Namespace(settings=str(default_settings_path()), scene="quick", out=str(tmp_path / "run"))
    text = io.StringIO()
    assert demo.prepare_run(args, prefix="demo", out=text)[1] == tmp_path / "run" / "fitted.npz"
    assert "fitted one on" in text.getvalue() and f"-> {tmp_path / 'run' / 'fitted.npz'}" in text.getvalue()
    assert capsys.readouterr().out == ""  # under --json stdout is the JSON alone
