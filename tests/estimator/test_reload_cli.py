"""``estimator reload`` binding the control endpoint: only an endpoint in use is another reload."""

from __future__ import annotations

import time

import pytest

from estimator import reload_cli
from estimator.cli import main
from teleop.bus import Publisher
from teleop.bus.security import init_keys
from teleop.errors import BusSecurityError, TeleopError
from teleop.settings import BusSettings


def test_keys_that_cannot_bind_are_said_as_they_are_without_waiting(tmp_path):
    init_keys(tmp_path / "bus")
    init_keys(tmp_path / "joined", server_cert=tmp_path / "bus" / "server.key")  # connect only
    bus = BusSettings(control="tcp://127.0.0.1:1", keys_dir=str(tmp_path / "joined"))
    started = time.monotonic()
    with pytest.raises(BusSecurityError, match="holds no server.key_secret") as caught:
        reload_cli._control_publisher(bus)
    assert time.monotonic() - started < reload_cli.BIND_WAIT_S / 2  # a retry cannot mend keys
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
