"""The live system's children without processes: the order they start and stop in, what is stopped
when the start fails, what its wait for readiness reports, and the grasp it follows (fakes throughout)."""

from __future__ import annotations

import contextlib
import dataclasses
import re
import signal
import subprocess
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from support.bus import ReplayedEvents, message_from

from teleop.catalogue import ObjectSpec
from teleop.errors import TeleopError
from teleop.node import COMMAND_TOPICS
from teleop.settings import default_settings_path, load_settings
from teleop.system import live_system
from teleop.system.live_system import (
    CHILDREN,
    GRASP_TIMEOUT_S,
    REPORT_TIMEOUT_S,
    LiveSystem,
    _Child,
    configured_calibration,
    grasp_timeout_s,
)

SPONGE = ObjectSpec(name="sponge", shape="box", material="foam", modulus_pa=3e4)


class _Process:
    """A child process: running until signalled (or ``code`` from the start), recording what it is sent."""

    def __init__(self, name: str, journal: list, *, code: int | None = None, deaf: bool = False):
        self.name, self.journal, self.code, self.deaf = name, journal, code, deaf
        self.pid = 0
        self.signalled: int | None = None

    def poll(self) -> int | None:
        return self.code

    def send_signal(self, sig: int) -> None:
        self.journal.append((self.name, "signal", sig))
        self.signalled = None if self.deaf else -sig

    def wait(self, timeout: float | None = None) -> int:
        self.journal.append((self.name, "wait", timeout))
        if self.code is None:
            self.code = self.signalled  # it exits once told, as it closes its files
        if self.code is None:
            raise subprocess.TimeoutExpired("child", timeout)
        return self.code

    def kill(self) -> None:
        self.journal.append((self.name, "kill"))
        self.code = -signal.SIGKILL


class _Socket:
    def __init__(self, journal: list, name: str):
        self.journal, self.name = journal, name

    def close(self) -> None:
        self.journal.append((self.name, "close"))


def _system(tmp_path: Path, **kwargs) -> LiveSystem:
    return LiveSystem(Path("settings.toml"), "quick", tmp_path, Path("calibration.npz"), **kwargs)


def _with_children(tmp_path: Path, journal: list, **processes: _Process) -> LiveSystem:
    system = _system(tmp_path)
    system.children = {name: _Child(name, process, tmp_path / f"{name}.log") for name, process in processes.items()}
    return system


def _exited(tmp_path: Path, name: str, code: int, log: str) -> LiveSystem:
    """A system whose child ``name`` exited with ``code``, having written ``log``."""
    system = _with_children(tmp_path, [], **{name: _Process(name, [], code=code)})
    (tmp_path / f"{name}.log").write_text(log)
    return system


def test_stop_stops_the_node_first_and_the_recorder_last_then_closes_the_bus_ends(tmp_path):
    journal: list = []
    system = _with_children(tmp_path, journal, **{name: _Process(name, journal) for name in CHILDREN})
    system.commands, system.events, system.control = (_Socket(journal, n) for n in ("commands", "events", "control"))
    codes = system.stop()
    signalled = [entry[0] for entry in journal if entry[1] == "signal"]
    assert signalled == ["node", "estimator", "renderer", "recorder"]  # the log gets everything
    assert all(entry[2] == signal.SIGTERM for entry in journal if entry[1] == "signal")  # asked, not killed
    # each one waited for before the next is told
    assert [e[0] for e in journal if e[1] in ("signal", "wait")] == [n for n in signalled for _ in range(2)]
    assert codes == {name: -signal.SIGTERM for name in CHILDREN}
    assert journal[-3:] == [("commands", "close"), ("events", "close"), ("control", "close")]


def test_stop_kills_a_child_that_does_not_stop_in_time_and_leaves_an_exited_one_alone(tmp_path):
    journal: list = []
    system = _with_children(tmp_path, journal, node=_Process("node", journal, deaf=True),
                            renderer=_Process("renderer", journal, code=3))
    codes = system.stop()
    assert ("node", "wait", live_system.STOP_TIMEOUT_S) in journal
    assert ("node", "kill") in journal and codes["node"] == -signal.SIGKILL
    assert not any(e[0] == "renderer" and e[1] in ("signal", "kill") for e in journal)
    assert codes["renderer"] == 3  # its own status, as it exited


@pytest.mark.parametrize("error", [TeleopError("live system not up"), KeyboardInterrupt()])
def test_a_start_that_fails_stops_what_it_started(tmp_path, monkeypatch, error):
    # A Ctrl-C during the wait too: no child is left running.
    system = _system(tmp_path, record=False)
    spawned: list[str] = []
    stopped: list[bool] = []
    monkeypatch.setattr(live_system, "load_settings", lambda path: load_settings(default_settings_path()))
    monkeypatch.setattr(system, "open_bus", lambda settings: setattr(system, "endpoints", dict.fromkeys(
        live_system.ENDPOINTS, "tcp://127.0.0.1:1")))
    monkeypatch.setattr(system, "_spawn", lambda name, line, env: spawned.append(name))
    monkeypatch.setattr(system, "stop", lambda: stopped.append(True))

    def fail(timeout_s):
        raise error

    monkeypatch.setattr(system, "_wait_ready", fail)
    with pytest.raises(type(error)):
        system.start(timeout_s=1.0)
    assert spawned == ["renderer", "estimator", "node"]  # no recorder without record; the node last
    assert stopped == [True]


def test_start_spawns_the_recorder_first_with_one_blas_thread_each(tmp_path, monkeypatch):
    system = LiveSystem(Path("settings.toml"), "quick", tmp_path / "out" / "run", Path("calibration.npz"))
    spawned: list[tuple[str, dict]] = []
    monkeypatch.setattr(live_system, "load_settings", lambda path: load_settings(default_settings_path()))
    monkeypatch.setattr(system, "open_bus", lambda settings: setattr(system, "endpoints", dict.fromkeys(
        live_system.ENDPOINTS, "tcp://127.0.0.1:1")))
    monkeypatch.setattr(system, "_spawn", lambda name, line, env: spawned.append((name, env)))
    monkeypatch.setattr(system, "_wait_ready", lambda timeout_s: None)
    system.start()
    assert system.run_dir.is_dir()
    assert [name for name, _ in spawned] == ["recorder", "renderer", "estimator", "node"]
    assert all(env["OMP_NUM_THREADS"] == "1" and env["TQDM_DISABLE"] == "1" for _, env in spawned)
    settings = load_settings(default_settings_path())
    assert system.grasp_timeout_s == grasp_timeout_s(settings) and system.display_range is not None


def test_a_grasp_is_given_the_closing_the_hold_and_a_margin_and_at_least_a_minute():
    settings = load_settings(default_settings_path())
    gripper = settings.gripper
    slow = dataclasses.replace(settings, gripper=dataclasses.replace(gripper, closing_speed_m_s=gripper.max_width_m / 100,
                                                                       hold_s=20.0))
    assert grasp_timeout_s(slow) == pytest.approx(100 + 20 + live_system.GRASP_MARGIN_S)
    assert grasp_timeout_s(settings) >= GRASP_TIMEOUT_S


class _Heard:
    """The operator's subscription: the peers heard, nothing else; waited on for long: a hang."""

    def __init__(self, peers):
        self.heartbeat = SimpleNamespace(peers=lambda: peers)
        self.waits: list[float] = []

    def recv(self, timeout_s: float):
        self.waits.append(timeout_s)
        if len(self.waits) > 100:
            raise AssertionError("still waiting long past the start's deadline")
        time.sleep(timeout_s)


class _Commands:
    def __init__(self, *prefixes: str):
        self.prefixes = prefixes

    def subscriptions(self, prefix: str) -> int:
        return self.prefixes.count(prefix)


def test_the_wait_for_readiness_names_who_stayed_silent_the_renderer_too(tmp_path):
    system = _system(tmp_path)
    system.events = _Heard(["robot", "estimator"])
    system.commands = _Commands(*COMMAND_TOPICS)  # the recorder has not subscribed
    with pytest.raises(TeleopError, match=r"not up within 0 s: nothing from renderer, the recorder; logs in "):
        system._wait_ready(0.0)


def test_a_child_that_exits_while_the_system_starts_is_reported_not_waited_out(tmp_path):
    system = _exited(tmp_path, "estimator", 1, "Traceback ...\nValueError: no calibration\n")
    system.events = _Heard([])
    system.commands = _Commands()
    with pytest.raises(TeleopError, match=r"(?s)estimator exited with status 1; the end of .*no calibration"):
        system._wait_ready(5.0)


def test_ready_once_every_peer_is_heard_and_then_settles(tmp_path):
    system = _system(tmp_path, record=False)
    system.events = _Heard(["robot", "estimator", "renderer"])
    system.commands = _Commands(*COMMAND_TOPICS)
    system._wait_ready(0.0)  # all there: no timeout raised
    assert system.events.waits and all(w <= live_system.SETTLE_S for w in system.events.waits)


def test_a_log_tail_is_its_last_lines(tmp_path):
    log = tmp_path / "node.log"
    log.write_text("".join(f"line {n}\n" for n in range(40)))
    tail = _Child("node", None, log).tail().splitlines()
    assert tail == [f"line {n}" for n in range(40 - live_system.LOG_TAIL_LINES, 40)]
    assert _Child("node", None, tmp_path / "missing.log").tail() == "(no log)"


def test_only_the_recorder_may_stop_with_the_recording_stopped_status(tmp_path):
    system = _exited(tmp_path, "node", live_system.RECORDING_STOPPED_STATUS, "node failed\n")
    with pytest.raises(TeleopError, match="node exited with status"):
        system.check()


def test_a_recorder_stopped_with_an_empty_log_still_lets_the_session_go_on(tmp_path, capsys):
    system = _exited(tmp_path, "recorder", live_system.RECORDING_STOPPED_STATUS, "")
    system.check()
    assert system.recording_stopped == "no reason in its log"


class _Waiting(ReplayedEvents):
    """Replaying ``messages``, then silent for each call's timeout; read on for long past any deadline: a hang."""

    def __init__(self, messages: list):
        super().__init__(messages)
        self.silent = 0

    def recv(self, timeout_s: float):
        if self.messages:
            return self.messages.pop(0)
        self.silent += 1
        if self.silent > 200:
            raise AssertionError("still reading the bus long past the grasp's deadline")
        time.sleep(timeout_s)
        return None


class _Sent:
    def __init__(self):
        self.sent: list[tuple[str, dict]] = []

    def send(self, topic: str, **fields) -> None:
        self.sent.append((topic, fields))


def _estimate(grasp_id: str, *, provisional: bool) -> object:
    return message_from("estimator", "estimate", grasp_id=grasp_id, method="analytical", E_pa=3e4, interval_pa=[2e4, 4e4],
                 state="ok", reason="", provisional=provisional, latency_s=0.01)


def test_a_commanded_grasp_counts_its_estimates_keeps_the_final_and_sees_every_message(tmp_path):
    system = _system(tmp_path)
    (tmp_path / "estimator.jsonl").write_text('{"grasp_id": "g1"}\n')
    (tmp_path / "renderer.jsonl").write_text('{"grasp_id": "g1"}\n')
    system.commands = _Sent()
    system.events = ReplayedEvents([
        message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="sponge"),
        message_from("estimator", "model_event", event="loaded", model="m1", reason=""),
        _estimate("g1", provisional=True),
        message_from("robot", "grasp_event", event="loading_end", grasp_id="g1"),
        _estimate("g1", provisional=False),
        _estimate("g1", provisional=True),
        message_from("estimator", "grasp_event", event="end", grasp_id="g1"),
        message_from("robot", "grasp_event", event="end", grasp_id="g1"),
    ])
    seen, updates = [], []
    outcome = system.grasp("g1", 2, SPONGE, on_message=seen.append, timeout_s=5.0,
                           on_update=lambda o: updates.append((o, o.estimator_report, o.robot_ended,
                                                               o.estimator_ended)))
    assert system.commands.sent == [("command", {"t_capture_s": pytest.approx(system.commands.sent[0][1][
        "t_capture_s"]), "action": "start_grasp", "grasp_id": "g1", "params": {"object_index": 2.0}})]
    assert outcome.started and outcome.robot_ended and outcome.estimator_ended
    assert outcome.estimates == 3 and outcome.final is not None and not outcome.final.provisional
    assert outcome.latest.provisional  # the latest, after the final
    assert len(seen) == 7 and all(m.type != "model_event" for m in seen)
    assert [e.model for e in system.model_events] == ["m1"]
    assert len(updates) == 8  # after each of its 7 messages, then with the reports
    assert [u[2:] for u in updates[-3:]] == [(False, True), (True, True), (True, True)]  # each its own end
    assert updates[-1][:2] == (outcome, {"grasp_id": "g1"})
    assert outcome.renderer_report == {"grasp_id": "g1"}


def test_a_loading_end_does_not_end_the_grasp(tmp_path):
    system = _system(tmp_path)
    system.commands = _Sent()
    system.events = _Waiting([
        message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="sponge"),
        message_from("robot", "grasp_event", event="loading_end", grasp_id="g1"),
        message_from("estimator", "grasp_event", event="loading_end", grasp_id="g1"),
    ])
    with pytest.raises(TeleopError, match=r"grasp g1 \(sponge\) did not end within 0.3 s"):
        system.grasp("g1", 0, SPONGE, timeout_s=0.3)


def test_only_the_robot_ends_its_side_of_the_grasp(tmp_path):
    system = _system(tmp_path)
    system.commands = _Sent()
    system.events = ReplayedEvents([
        message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="sponge"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g1"),
    ])
    with pytest.raises(TeleopError, match="did not end within"):
        system.grasp("g1", 0, SPONGE, timeout_s=0.3)


def test_the_node_grasping_another_object_is_refused_naming_both(tmp_path):
    system = _system(tmp_path)
    system.commands = _Sent()
    system.events = ReplayedEvents([message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="duck")])
    with pytest.raises(TeleopError, match="grasp g1: the node grasped duck, not sponge"):
        system.grasp("g1", 0, SPONGE, timeout_s=5.0)


def test_a_child_that_dies_mid_grasp_is_reported_not_waited_out(tmp_path):
    system = _exited(tmp_path, "node", -9, "killed\n")
    system.commands = _Sent()
    system.events = ReplayedEvents([])
    with pytest.raises(TeleopError, match="node exited with status -9"):
        system.grasp("g1", 0, SPONGE, timeout_s=5.0)


def test_an_operated_grasp_is_the_robots_start_not_the_estimators_nor_one_already_followed(tmp_path):
    system = _system(tmp_path)
    (tmp_path / "estimator.jsonl").write_text('{"grasp_id": "g2"}\n')
    system._followed.add("g1")
    system.events = ReplayedEvents([
        message_from("estimator", "grasp_event", event="start", grasp_id="g0", object_name="sponge"),
        message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="sponge"),
        message_from("robot", "grasp_event", event="start", grasp_id="g2", object_name="sponge"),
        message_from("robot", "grasp_event", event="end", grasp_id="g2"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g2"),
    ])
    outcome = system.operated_grasp(SPONGE, timeout_s=5.0)
    assert outcome.grasp_id == "g2" and outcome.style == "operator"
    assert system._later == []  # neither the estimator's g0 nor g1 (followed) kept for later


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), True])
def test_a_grasps_timeout_defaults_to_the_settings_and_a_bad_one_commands_nothing(tmp_path, monkeypatch, bad):
    system = _system(tmp_path)
    system.commands = _Sent()
    system.grasp_timeout_s = 123.0
    given: list[float] = []
    monkeypatch.setattr(system, "_follow", lambda outcome, **kw: given.append(kw["timeout_s"]))
    system.grasp("g1", 0, SPONGE)
    system.operated_grasp(SPONGE, timeout_s=7)
    assert given == [123.0, 7.0] and len(system.commands.sent) == 1
    for grasp in (lambda: system.grasp("g2", 0, SPONGE, timeout_s=bad), lambda: system.operated_grasp(SPONGE, timeout_s=bad)):
        with pytest.raises(ValueError, match="timeout_s"):
            grasp()
    assert len(system.commands.sent) == 1 and len(given) == 2


def test_the_children_are_spawned_in_their_own_session_to_die_with_this_process(tmp_path, monkeypatch):
    calls: list = []
    monkeypatch.setattr(live_system.subprocess, "Popen", lambda argv, **kwargs: calls.append((argv, kwargs)))
    system = _system(tmp_path)
    system._spawn("node", ["teleop", "node", "--scene", "quick"], {"A": "1"})
    (argv, kwargs), = calls
    assert argv[1:3] == ["-P", "-c"] and argv[-3:] == ["node", "--scene", "quick"]
    assert "from teleop.cli import main" in argv[3]
    assert kwargs["start_new_session"] is True and kwargs["preexec_fn"] is live_system._die_with_parent
    assert kwargs["stdin"] == subprocess.DEVNULL and kwargs["stderr"] == subprocess.STDOUT
    assert kwargs["env"] == {"A": "1"} and system.children["node"].log_path == tmp_path / "node.log"


def test_a_child_is_told_by_the_kernel_to_stop_when_its_parent_dies(monkeypatch):
    calls: list = []
    monkeypatch.setattr(live_system, "_prctl", lambda *args: calls.append(args))
    live_system._die_with_parent()
    assert calls == [(1, signal.SIGTERM)]  # PR_SET_PDEATHSIG: a stop it can close its files on


def test_the_command_lines_name_the_model_the_recorder_and_its_foxglove_view(tmp_path):
    system = _system(tmp_path, foxglove=("127.0.0.1", 8765), model="none")
    system.endpoints = {name: f"tcp://127.0.0.1:{n}" for n, name in enumerate(live_system.ENDPOINTS, start=1)}
    lines = system._command_lines()
    assert lines["estimator"][-2:] == ["--model", "none"]
    assert lines["recorder"][-2:] == ["--foxglove", "127.0.0.1:8765"]
    assert lines["recorder"][3] == str(tmp_path / "session.mcap") == str(system.session_log)
    plain = _system(tmp_path, record=False)
    plain.endpoints = system.endpoints
    assert "--model" not in plain._command_lines()["estimator"] and "recorder" not in plain._command_lines()
    assert plain.session_log is None
    empty = _system(tmp_path, model="")
    empty.endpoints = system.endpoints
    assert empty._command_lines()["estimator"][-2:] == ["--model", ""]  # given: passed on for the CLI to judge


def test_the_operators_bus_ends_take_every_peer_and_send_commands_losslessly(tmp_path):
    from teleop.settings import default_settings_path as shipped

    system = LiveSystem(shipped(), "quick", tmp_path, tmp_path / "calibration.npz")
    try:
        system.open_bus(load_settings(shipped()))
        bus = system.bus
        assert system.commands.lossless and system.commands.source == "operator"
        assert system.events.endpoints == [bus.robot_pub, bus.estimate_pub, bus.display_pub]
        assert {"grasp_event", "estimate", "force", "display", "model_event", "robot_notice"} <= set(system.events.topics)
    finally:
        system.stop()


def test_a_configured_calibration_is_the_file_the_settings_name_when_it_is_there(tmp_path):
    settings = load_settings(default_settings_path())
    finger = settings.sensing.finger

    def naming(value: str):
        sensors = [dataclasses.replace(s, calibration=value) if s.finger == finger else s for s in settings.sensors]
        return dataclasses.replace(settings, sensors=sensors)

    (tmp_path / "cal.npz").write_bytes(b"")
    assert configured_calibration(naming(str(tmp_path / "cal.npz"))) == tmp_path / "cal.npz"
    assert configured_calibration(naming(str(tmp_path / "missing.npz"))) is None
    assert configured_calibration(naming(str(tmp_path))) is None  # a folder is no calibration
    assert configured_calibration(naming("")) is None


def test_an_empty_log_says_how_much_room_its_folder_has(tmp_path):
    log = tmp_path / "node.log"
    log.write_bytes(b"")
    assert re.search(r"\(free: \d+ MB\)$", _Child("node", None, log).why_silent())


def test_leaving_the_system_stops_it_with_sigterm_and_sighup_ignored_too(tmp_path):
    system = _system(tmp_path)
    seen: list = []
    system.stop = lambda: seen.append([signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)])
    system.__exit__(None, None, None)
    assert seen == [[signal.SIG_IGN] * 3]


class _Reports:
    def __init__(self, record):
        self.record, self.timeouts = record, []

    def find(self, grasp_id: str, *, timeout_s: float):
        self.timeouts.append(timeout_s)
        return self.record


@pytest.mark.parametrize("final", [True, False])
def test_the_renderers_report_is_waited_for_only_for_a_grasp_with_a_final_estimate(tmp_path, final):
    system = _system(tmp_path)
    system.commands = _Sent()
    system.estimator_reports, system.renderer_reports = _Reports({"e": 1}), _Reports(None)
    system.events = ReplayedEvents([
        message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="sponge"),
        *([_estimate("g1", provisional=False)] if final else []),
        message_from("estimator", "grasp_event", event="end", grasp_id="g1"),
        message_from("robot", "grasp_event", event="end", grasp_id="g1"),
    ])
    outcome = system.grasp("g1", 0, SPONGE, timeout_s=5.0)
    assert system.estimator_reports.timeouts == [REPORT_TIMEOUT_S]
    assert system.renderer_reports.timeouts == [REPORT_TIMEOUT_S if final else 0.0]
    assert outcome.estimator_report == {"e": 1} and "g1" in system._followed


def _reloading(tmp_path: Path, monkeypatch, reload_model) -> tuple[LiveSystem, list]:
    import estimator.reload_cli

    system = _system(tmp_path)
    system.bus = SimpleNamespace(control="tcp://127.0.0.1:1", estimate_pub="tcp://127.0.0.1:2")
    made: list = []
    monkeypatch.setattr(live_system.Publisher, "from_settings",
                        lambda bus, endpoint, **kwargs: made.append(kwargs) or _Socket([], "control"))
    monkeypatch.setattr(live_system.Subscriber, "from_settings", lambda *args, **kwargs: contextlib.nullcontext())
    monkeypatch.setattr(estimator.reload_cli, "reload_model", reload_model)
    return system, made


def test_load_model_sends_the_absolute_path_on_one_control_publisher_kept_between_loads(tmp_path, monkeypatch):
    asked: list = []
    system, made = _reloading(tmp_path, monkeypatch, lambda path, **kw: asked.append((path, kw["command"])) or "ok")
    monkeypatch.chdir(tmp_path)
    assert system.load_model("models/a") == "ok" and system.load_model("models/b") == "ok"
    assert [p for p, _ in asked] == [str(tmp_path / "models/a"), str(tmp_path / "models/b")]
    assert len(made) == 1 and asked[0][1] is asked[1][1] is system.control


def test_load_model_on_a_system_whose_child_died_says_so_before_and_after(tmp_path, monkeypatch):
    journal: list = []

    def no_answer(path, **kwargs):
        system.children["estimator"] = _Child("estimator", _Process("estimator", journal, code=1),
                                              tmp_path / "estimator.log")
        raise TeleopError("no answer from the estimator")

    (tmp_path / "estimator.log").write_text("MemoryError\n")
    system, _ = _reloading(tmp_path, monkeypatch, no_answer)
    with pytest.raises(TeleopError, match="estimator exited with status 1"):
        system.load_model("m")  # the died child, the better reason than no answer
    asked: list = []
    system, _ = _reloading(tmp_path, monkeypatch, lambda path, **kw: asked.append(path))
    system.children["node"] = _Child("node", _Process("node", journal, code=2), tmp_path / "estimator.log")
    with pytest.raises(TeleopError, match="node exited with status 2"):
        system.load_model("m")
    assert asked == []  # not sent to a system already down


def test_a_child_that_exits_cleanly_before_it_is_told_still_stops_the_system(tmp_path):
    # Status 0 is no less an early exit: the node gone, no grasp would ever end.
    system = _exited(tmp_path, "node", 0, "bye\n")
    with pytest.raises(TeleopError, match="node exited with status 0"):
        system.check()


def test_the_recording_stopped_reason_is_the_recorders_last_line(tmp_path, capsys):
    system = _exited(tmp_path, "recorder", live_system.RECORDING_STOPPED_STATUS,
                     f"wrote 12 messages\n{live_system.RECORDING_STOPPED}disk full\n")
    system.check()
    assert system.recording_stopped == "disk full"


def test_what_an_earlier_grasp_set_aside_is_taken_in_the_order_it_came(tmp_path):
    # The operator's second grasp ran its whole course while the first was followed.
    system = _system(tmp_path)
    (tmp_path / "estimator.jsonl").write_text("".join(f'{{"grasp_id": "g{n}"}}\n' for n in (1, 2)))
    system.events = ReplayedEvents([
        message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="sponge"),
        message_from("robot", "grasp_event", event="end", grasp_id="g1"),
        message_from("robot", "grasp_event", event="start", grasp_id="g2", object_name="sponge"),
        _estimate("g2", provisional=True),
        _estimate("g2", provisional=False),
        message_from("robot", "grasp_event", event="end", grasp_id="g2"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g2"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g1"),
    ])
    assert system.operated_grasp(SPONGE, timeout_s=2.0).grasp_id == "g1"
    second = system.operated_grasp(SPONGE, timeout_s=2.0)
    assert second.grasp_id == "g2" and second.estimates == 2 and second.latest is second.final


def test_a_grasp_that_started_before_the_last_one_ended_keeps_its_end_once_set_aside_twice(tmp_path):
    # The estimator ends g2 after the robot started g3, and g1 after all of it: following g2 from
    # what g1 set aside, g3's start is set aside again while g3's ends are not reached yet; they
    # came after its start and must wait behind it, or the third grasp, seeing its ends before its
    # start, drops them and waits out its timeout.
    system = _system(tmp_path)
    (tmp_path / "estimator.jsonl").write_text("".join(f'{{"grasp_id": "g{n}"}}\n' for n in (1, 2, 3)))
    system.events = ReplayedEvents([
        message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="sponge"),
        message_from("robot", "grasp_event", event="end", grasp_id="g1"),
        message_from("robot", "grasp_event", event="start", grasp_id="g2", object_name="sponge"),
        message_from("robot", "grasp_event", event="end", grasp_id="g2"),
        message_from("robot", "grasp_event", event="start", grasp_id="g3", object_name="sponge"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g2"),
        message_from("robot", "grasp_event", event="end", grasp_id="g3"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g3"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g1"),
    ])
    followed = [system.operated_grasp(SPONGE, timeout_s=2.0) for _ in range(3)]
    assert [o.grasp_id for o in followed] == ["g1", "g2", "g3"]
    assert all(o.robot_ended and o.estimator_ended for o in followed)


def test_only_what_belongs_to_a_grasp_yet_to_come_is_set_aside(tmp_path):
    # A late message of a grasp already followed, and a notice that ends nothing (a stale follow
    # refused), are no later grasp's: kept, they would pile up for grasps that never take them.
    system = _system(tmp_path)
    (tmp_path / "estimator.jsonl").write_text('{"grasp_id": "g1"}\n')
    system._followed.add("g0")
    system.events = ReplayedEvents([
        message_from("robot", "grasp_event", event="start", grasp_id="g1", object_name="sponge"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g0"),
        message_from("robot", "robot_notice", event="refused", action="follow", grasp_id="g2", reason="ended"),
        message_from("robot", "robot_notice", event="watchdog", action="follow", grasp_id="g3", reason="stalled"),
        message_from("robot", "grasp_event", event="end", grasp_id="g1"),
        message_from("estimator", "grasp_event", event="end", grasp_id="g1"),
    ])
    assert system.operated_grasp(SPONGE, timeout_s=2.0).grasp_id == "g1"
    assert [(m.type, m.fields.grasp_id) for m in system._later] == [("robot_notice", "g3")]
