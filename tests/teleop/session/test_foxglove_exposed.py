"""A live view other hosts can reach is served with a warning naming the risk: unlike the bus, it runs
no CURVE (teleop.session.foxglove_live.LiveServer)."""

from __future__ import annotations

import logging

from teleop.session.foxglove_live import LiveServer


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.name == "teleop.session.foxglove_live" and r.levelno == logging.WARNING]


def test_a_live_view_off_loopback_warns_that_anyone_on_the_network_can_watch(caplog):
    caplog.set_level(logging.WARNING, logger="teleop.session.foxglove_live")
    with LiveServer("127.0.0.1", 0), LiveServer("localhost", 0):
        assert _warnings(caplog) == []
    with LiveServer("0.0.0.0", 0) as server:
        [warning] = _warnings(caplog)
        url, port = server.url, server.port
    assert f"{url} is reachable from other hosts, unencrypted and without authentication" in warning
    assert "serve it on 127.0.0.1" in warning and f"ssh -L {port}:127.0.0.1:{port}" in warning
