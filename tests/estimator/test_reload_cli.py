"""``estimator reload`` binding the control endpoint: only an endpoint in use is another reload."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest

from estimator import reload_cli
from estimator.cli import main
from teleop.bus import Publisher, Subscriber
from teleop.bus.security import init_keys
from teleop.errors import BusSecurityError, TeleopError
from teleop.settings import BusSettings


def test_keys_that_cannot_bind_are_said_as_they_are_without_waiting(tmp_path, monkeypatch):
    init_keys(tmp_path / "bus")
    init_keys(tmp_path / "joined", server_cert=tmp_path / "bus" / "server.key")  # connect only
    bus = BusSettings(control="tcp://127.0.0.1:1", keys_dir=str(tmp_path / "joined"))

    def waiting(seconds):
        pytest.fail("waited to retry: a retry cannot mend keys")

    monkeypatch.setattr(reload_cli.time, "sleep", waiting)
    with pytest.raises(BusSecurityError, match="holds no server.key_secret") as caught:
        reload_cli._control_publisher(bus)
    assert "another estimator reload" not in str(caught.value)


def test_a_control_endpoint_in_use_is_waited_for_then_blamed_on_another_reload(monkeypatch):
    monkeypatch.setattr(reload_cli, "BIND_WAIT_S", 0.2)
    with Publisher("tcp://127.0.0.1:*", lossless=False) as holder, \
            pytest.raises(TeleopError, match="another estimator reload runs"):
        reload_cli._control_publisher(BusSettings(control=holder.endpoint))


@pytest.mark.parametrize("timeout_s", ["nan", "inf", "0", "-1", "soon"])
def test_a_timeout_that_is_no_finite_time_is_a_usage_error_before_anything_waits(timeout_s, tmp_path, capsys,
                                                                                 monkeypatch):
    # nan passed a `<= 0` check and waited for ever for a service that did not answer.
    def waits(*args, **kwargs):
        raise AssertionError("waited for an answer with --timeout-s " + timeout_s)

    monkeypatch.setattr(reload_cli, "reload_model", waits)
    with pytest.raises(SystemExit) as exited:
        main(["reload", "--model", str(tmp_path), "--timeout-s", timeout_s])
    assert exited.value.code == 2
    assert f"argument --timeout-s: {timeout_s!r}: expected a number > 0" in capsys.readouterr().err


@pytest.mark.slow
def test_the_request_waits_for_the_services_subscription_and_the_recorders(monkeypatch):
    # On a freshly bound control endpoint the first request went before anyone had subscribed and was
    # lost; and a service answering before a recorder joined left the request off the session's record.
    monkeypatch.setattr(reload_cli, "RESEND_S", 60.0)  # one send, or no answer in time
    monkeypatch.setattr(reload_cli, "JOIN_S", 1.0)
    heard: list = []
    with Publisher("tcp://127.0.0.1:*", lossless=False) as control, \
            Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator") as service_pub, \
            Subscriber(service_pub.endpoint, ("model_event",)) as answers:

        def peers_join_late_then_serve():
            time.sleep(0.2)
            with Subscriber(control.endpoint, ("load_model",)) as service:
                time.sleep(0.2)
                with Subscriber(control.endpoint, ("",)) as recorder:
                    message = service.recv(timeout_s=8.0)
                    service_pub.wait_for_subscriber("model_event")
                    service_pub.send("model_event", t_capture_s=0.0, event="loaded", request=message.fields.request,
                                     model="m", path=message.fields.path, reason="")
                    heard.append(recorder.recv(timeout_s=2.0))

        thread = threading.Thread(target=peers_join_late_then_serve, daemon=True)
        thread.start()
        answer = reload_cli.reload_model("/models/b", command=control, answers=answers, timeout_s=8.0)
        thread.join(timeout=5.0)
    assert answer.event == "loaded" and control.sent == 1
    assert heard[0] is not None and heard[0].type == "load_model" and heard[0].fields.request == answer.request


def test_no_service_on_the_control_endpoint_is_said_a_recorder_there_is_not_one(tmp_path):
    with Publisher("tcp://127.0.0.1:*", lossless=False) as control, \
            Subscriber(control.endpoint, ("",)) as recorder, \
            Subscriber("tcp://127.0.0.1:1", ("model_event",)) as answers:
        control.wait_for_subscriber("")
        with pytest.raises(TeleopError, match="nothing subscribed to load_model on tcp://127.0.0.1:") as caught:
            reload_cli.reload_model("/models/b", command=control, answers=answers, timeout_s=0.5)
        assert recorder.recv(timeout_s=0) is None
    assert control.sent == 0 and "--estimate-pub tcp://127.0.0.1:1" in str(caught.value)


def test_the_answer_says_how_many_services_took_the_request(tmp_path, capsys):
    # A second service on the control endpoint (serving another model, side by side) switched too,
    # and the answer named only the one on the estimate endpoint.
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        control = f"tcp://127.0.0.1:{probe.getsockname()[1]}"
    took: list = []
    with Publisher("tcp://127.0.0.1:*", lossless=False, source="estimator") as service_pub, \
            Subscriber(control, ("load_model",)) as service, Subscriber(control, ("load_model",)) as other, \
            Subscriber(control, ("",)):  # a recorder: no service

        def serve():
            message = service.recv(timeout_s=8.0)
            took.append(other.recv(timeout_s=2.0))
            service_pub.wait_for_subscriber("model_event")
            service_pub.send("model_event", t_capture_s=0.0, event="loaded", request=message.fields.request,
                             model="m", path=message.fields.path, reason="")

        thread = threading.Thread(target=serve, daemon=True)
        thread.start()
        code = main(["reload", "--model", str(tmp_path), "--control", control,
                     "--estimate-pub", service_pub.endpoint, "--timeout-s", "8", "--json"])
        thread.join(timeout=5.0)
    out, err = capsys.readouterr()
    assert code == 0 and took[0] is not None and took[0].type == "load_model"
    assert json.loads(out.splitlines()[-1])["services"] == 2
    assert f"2 estimator services subscribe to {control}: every one took this load_model" in err
    assert "give each service its own --control" in err
