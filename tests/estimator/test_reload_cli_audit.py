"""``estimator reload`` on a fake bus and a fake clock: when the request goes and goes again, which
answer is its own, what a timeout blames, and what the command prints and exits with."""

from __future__ import annotations

import argparse
import json
import os
import re
from types import SimpleNamespace

import pytest
from support.operator_fakes import Clock

from estimator import reload_cli
from estimator.errors import ModelError
from teleop.errors import BusAddressInUseError, BusError, TeleopError


class Command:
    """The control endpoint: its subscriptions by topic from ``joined_s`` on, and what was sent."""

    endpoint = "tcp://127.0.0.1:5001"

    def __init__(self, clock: Clock, subscribed: dict[str, int], joined_s: float = 0.0):
        self.clock, self.subscribed, self.joined_s = clock, subscribed, joined_s
        self.sent: list[tuple[float, dict]] = []

    def subscriptions(self, prefix: str) -> int:
        return self.subscribed.get(prefix, 0) if self.clock() >= self.joined_s else 0

    def send(self, topic: str, **fields) -> None:
        assert topic == "load_model"
        self.sent.append((self.clock(), fields))


class Answers:
    """The estimate endpoint: hands out ``script(sent)``'s messages, each wait taking its timeout (at
    least 10 ms)."""

    endpoint_text = "tcp://127.0.0.1:5002"

    def __init__(self, clock: Clock, command: Command, script, alive: bool = True):
        self.clock, self.command, self.script = clock, command, script
        self.heartbeat = SimpleNamespace(is_alive=lambda source: alive and source == "estimator")
        self.pending: list = []

    def recv(self, timeout_s: float):
        self.pending += self.script(self.command.sent)
        self.clock.t += max(timeout_s, 0.01)
        return self.pending.pop(0) if self.pending else None


def answer(request: str | None, event: str = "loaded", kind: str = "model_event"):
    return SimpleNamespace(type=kind, fields=SimpleNamespace(event=event, request=request, model="m", path="/p",
                                                             reason=""))


@pytest.fixture
def clock(monkeypatch) -> Clock:
    clock = Clock()
    monkeypatch.setattr(reload_cli, "time", SimpleNamespace(monotonic=clock, sleep=lambda s: setattr(
        clock, "t", clock.t + s)))
    return clock


def test_the_request_goes_join_s_after_the_service_subscribed_and_again_every_resend_s_until_answered(clock):
    command = Command(clock, {"load_model": 1}, joined_s=clock.t + 1.0)

    def on_third(sent):
        return [answer(sent[-1][1]["request"])] if len(sent) == 3 else []

    got = reload_cli.reload_model("/m", command=command, answers=Answers(clock, command, on_third), timeout_s=10.0,
                                  request="r1")
    times = [t for t, _ in command.sent]
    assert got.request == "r1" and len(times) == 3
    assert times[0] == pytest.approx(command.joined_s + reload_cli.JOIN_S, abs=0.11)
    assert [b - a for a, b in zip(times, times[1:], strict=False)] == pytest.approx([reload_cli.RESEND_S] * 2, abs=0.11)
    assert all(fields == {"t_capture_s": t, "path": "/m", "request": "r1"} for t, fields in command.sent)


def test_an_answer_to_another_request_or_another_message_is_not_the_answer(clock):
    command = Command(clock, {"load_model": 2})

    def others_first(sent):
        if len(sent) != 1:
            return []
        return [answer("someone-else", "refused"), answer("r1", "refused", kind="estimate"), answer("r1")]

    got = reload_cli.reload_model("/m", command=command, answers=Answers(clock, command, others_first), timeout_s=5.0,
                                  request="r1")
    assert (got.event, got.request) == ("loaded", "r1")


def test_each_reload_names_its_request_by_this_process_and_a_random_part(clock):
    requests = []
    for _ in range(2):
        command = Command(clock, {"load_model": 1})
        got = reload_cli.reload_model("/m", command=command, timeout_s=5.0, answers=Answers(
            clock, command, lambda sent: [answer(sent[0][1]["request"])] if sent else []))
        requests.append(got.request)
    assert all(re.fullmatch(rf"reload-{os.getpid()}-[0-9a-f]{{8}}", r) for r in requests)
    assert requests[0] != requests[1]


@pytest.mark.parametrize(("subscribed", "alive", "blamed"), [
    ({"": 1}, True, "nothing subscribed to load_model on tcp://127.0.0.1:5001"),
    ({"load_model": 1}, True, "is running: it switches models between grasps, so a grasp still open"),
    ({"load_model": 1}, False, "this did not hear the estimator service on tcp://127.0.0.1:5002"),
])
def test_a_timeout_blames_what_was_not_heard(clock, subscribed, alive, blamed):
    command, start = Command(clock, subscribed), clock.t
    with pytest.raises(TeleopError, match="no answer to load_model /m") as caught:
        reload_cli.reload_model("/m", command=command, answers=Answers(clock, command, lambda sent: [], alive=alive),
                                timeout_s=2.0)
    assert blamed in str(caught.value)
    assert clock.t - start == pytest.approx(2.0, abs=0.06)


def test_services_reached_counts_subscribers_to_load_model_not_recorders(clock):
    assert reload_cli.services_reached(Command(clock, {"": 3, "load_model": 2})) == 2


def test_a_control_endpoint_freed_within_the_bind_wait_is_bound(clock, monkeypatch):
    tries = []

    def from_settings(bus, endpoint, **kwargs):
        tries.append(clock())
        if len(tries) < 3:
            raise BusAddressInUseError("address in use")
        return "publisher"

    monkeypatch.setattr(reload_cli.Publisher, "from_settings", from_settings)
    assert reload_cli._control_publisher(SimpleNamespace(control="tcp://127.0.0.1:5001")) == "publisher"
    assert len(tries) == 3 and tries[-1] - tries[0] < reload_cli.BIND_WAIT_S


class Closing:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def subscriptions(self, prefix: str) -> int:
        return self.services if prefix == "load_model" else 9


def run_reload(monkeypatch, argv: list[str], event: str = "loaded", services: int = 1) -> tuple[int, dict]:
    """``run`` with ``argv`` answered by ``event``, ``services`` subscribed: its exit status and what
    ``reload_model`` was given."""
    given = {}
    publisher = Closing()
    publisher.services = services

    def reload_model(path, *, command, answers, timeout_s):
        given.update(path=path, timeout_s=timeout_s)
        return reload_cli.ModelEventBody(event=event, request="r1", model="m-1", path=path, reason="bad")

    monkeypatch.setattr(reload_cli.Subscriber, "from_settings", lambda *a, **k: Closing())
    monkeypatch.setattr(reload_cli, "_control_publisher", lambda bus: publisher)
    monkeypatch.setattr(reload_cli, "reload_model", reload_model)
    parser = argparse.ArgumentParser()
    reload_cli.add_arguments(parser)
    return reload_cli.run(parser.parse_args(argv)), given


def test_a_relative_model_path_is_sent_absolute_with_the_timeout_asked_for(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    code, given = run_reload(monkeypatch, ["--model", "models/b", "--timeout-s", "7"])
    assert code == 0 and given == {"path": str(tmp_path / "models" / "b"), "timeout_s": 7.0}


def test_a_refusal_exits_1_and_json_is_printed_only_when_asked_for(monkeypatch, capsys):
    code, _ = run_reload(monkeypatch, ["--model", "/m"], event="refused")
    out, err = capsys.readouterr()
    assert code == 1 and out == "" and "refused /m: bad; the service keeps m-1" in err


def test_one_service_or_one_gone_since_answering_is_counted_one_and_not_warned_about(monkeypatch, capsys):
    for services in (0, 1):
        code, _ = run_reload(monkeypatch, ["--model", "/m", "--json"], services=services)
        out, err = capsys.readouterr()
        assert code == 0 and json.loads(out.splitlines()[-1])["services"] == 1
        assert "estimator services subscribe" not in err


def test_an_empty_model_path_is_refused_before_the_bus_is_touched(monkeypatch):
    with pytest.raises(ModelError, match="--model: expected a model folder"):
        run_reload(monkeypatch, ["--model", "  "])


def test_an_estimate_endpoint_that_cannot_be_listened_to_is_said_so(monkeypatch):
    def unusable(*args, **kwargs):
        raise BusError("bad endpoint")

    parser = argparse.ArgumentParser()
    reload_cli.add_arguments(parser)
    monkeypatch.setattr(reload_cli.Subscriber, "from_settings", unusable)
    with pytest.raises(TeleopError, match="cannot listen to the estimator service on .*bad endpoint"):
        reload_cli.run(parser.parse_args(["--model", "/m"]))
